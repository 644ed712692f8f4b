"""``bvae bench rd``: held-out rate–distortion rows in file bytes against PCA of the same training materials."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path

import pytest

from brdfcodec.datasets.hdf5 import build_dataset
from brdfcodec.datasets.sources import analytic_sources
from brdfcodec.models.config import TINY_CONFIG
from brdfcodec.training.config import TrainConfig
from brdfcodec.training.export import export_run
from brdfcodec.training.trainer import train


@pytest.fixture(scope="module")
def fold_model(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("rd-runner")
    dataset = folder / "data.h5"
    build_dataset(dataset, analytic_sources(random_count=7), source_kind="analytic", description="analytic",
                  progress=False)
    config = TrainConfig(epochs=1, batch_size=4, learning_rate=1e-3, warmup_epochs=1, eval_every=1, seed=3,
                         folds=3, fold=0, keep="last")
    train(dataset, folder / "run", model_config=dataclasses.replace(TINY_CONFIG, linear_basis=True),
          train_config=config, progress=False)
    export_run(folder / "run", folder / "model", name="rd-runner-test", basis_count=8)
    return dataset, folder / "model"


@pytest.mark.slow  # trains, exports and encodes: > 10 s on 2 cores
def test_rows_compare_file_bytes_with_pca_of_the_same_training_materials(fold_model: tuple[Path, Path],
                                                                         tmp_path: Path, monkeypatch) -> None:
    import brdfcodec
    from brdfcodec.cli.main import main
    from brdfcodec.report.rows import SCHEMA, read_rows

    dataset, model = fold_model
    asked: list[object] = []  # what the runner's encodes were asked for: the experiment's coded-μ grid
    real_encode = brdfcodec.encode
    references: list[object] = []

    def encode(*args: object, **options: object) -> bytes:
        asked.append(options.get("coded_mu_step"))
        references.append(options.get("short_references"))
        return real_encode(*args, **options)  # type: ignore[arg-type]

    monkeypatch.setattr(brdfcodec, "encode", encode)
    config = tmp_path / "rd.json"
    config.write_text(json.dumps({"dataset": str(dataset), "budgets": [32, 64],
                                  "experiments": [{"label": "fold0", "model": str(model), "group": "cv",
                                                   "coded_mu_step": 2}]}))
    assert main(["bench", "rd", "--config", str(config), "-o", str(tmp_path / "rows.jsonl"), "--quiet"]) == 0
    rows = read_rows(tmp_path / "rows.jsonl")
    manifest = json.loads((model / "model.json").read_text())
    held = set(manifest["info"]["data"]["validation"])
    assert rows and all(row["schema"] == SCHEMA and row["commit"] and row["group"] == "cv" for row in rows)
    # every row names the decoder and the shared basis its records were made with
    assert manifest["basis_sha256"] and all(row["basis_sha256"] == manifest["basis_sha256"] and
                                            row["decoder_sha256"] == manifest["decoder_sha256"] for row in rows)
    ours = [row for row in rows if row["point"] == "bvae"]
    assert {row["budget_bytes"] for row in ours} == {32, 64}
    assert all(row["coded_mu_step"] == 2 for row in ours)  # the experiment's grid, named in its rows
    assert asked and set(asked) == {2}
    assert set(references) == {True} and all(row["short_references"] is True for row in ours)  # the default
    for row in ours:
        assert set(row["materials"]) <= held and len(row["per_material_mapped"]) == len(row["materials"])
        names = sum(len(n.encode()) for n in row["materials"])
        # a sum of record bytes over n plus the header's share: equal to the file's bytes over n up to rounding
        assert row["bytes_per_material"] == pytest.approx((row["file_bytes"] - names) / len(row["materials"]),
                                                          rel=1e-12)
        assert row["bytes_per_material"] <= row["budget_bytes"] and row["bytes_flag"] <= row["budget_bytes"]
        # the header's share is charged: below the records' saturation (8 basis vectors here), --bytes is below N
        assert row["bytes_flag"] < row["budget_bytes"] or row["bytes_per_material"] < row["budget_bytes"] - 8
    pca = {row["point"] for row in rows} - {"bvae"}
    assert pca == {f"{base}-{kind}" for base in ("pca", "pca-perm")
                   for kind in ("int8", "float16", "tc", "ec-laplace", "ec-gaussian")}
    coded = [row for row in rows if row["point"].endswith(("-tc", "-ec-laplace", "-ec-gaussian"))]
    assert all(row["bytes_max"] <= row["budget_bytes"] for row in coded)
    # Plain PCA of 2/3 of 14 materials has at most 8 components: k is capped at the basis' rank.
    plain = [row for row in rows if row["point"] == "pca-int8" and row["budget_bytes"] == 64]
    assert plain[0]["coefficients"] <= 8
    # Every point, brdfcodec's and each PCA's, carries its decode time per material and the machine's name.
    assert all(row["decode_ms_median"] > 0 and row["decode_ms_mean"] > 0 for row in rows)
    assert all(row["decode_machine"].startswith("CPU: ") for row in rows)
    assert main(["bench", "table", str(tmp_path / "rows.jsonl"), "-o", str(tmp_path / "table.md"),
                 "--plot", str(tmp_path / "rd.png"), "--time-plot", str(tmp_path / "time.png")]) == 0
    assert (tmp_path / "rd.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (tmp_path / "time.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = (tmp_path / "table.md").read_text()
    assert "**cv, held-out analytic**" in table and "| 64 B |" in table


@pytest.mark.slow  # trains, exports and encodes: > 10 s on 2 cores
def test_pca_with_edge_slots_codes_the_filled_slices(fold_model: tuple[Path, Path], tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """``"pca_edge_slots": true`` adds every PCA point again, fitted and coded with the edge slots filled: the
    same kinds with finite errors, and the slices the edge points code hold each held-out material's edge
    targets at its edge slots (the plain points' hold 0 there)."""
    import numpy as np

    from brdfcodec.datasets.hdf5 import BrdfDataset
    from brdfcodec.report import generalisation
    from brdfcodec.representation.edge_slots import edge_slot_targets

    coded: dict[str, np.ndarray] = {}
    real_pca_rows = generalisation._pca_rows

    def pca_rows(name: str, basis: object, inputs: np.ndarray, *args: object) -> list[dict]:
        coded[name] = np.array(inputs)
        return real_pca_rows(name, basis, inputs, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(generalisation, "_pca_rows", pca_rows)
    dataset, model = fold_model
    config = tmp_path / "rd.json"
    config.write_text(json.dumps({"dataset": str(dataset), "budgets": [64], "pca_edge_slots": True,
                                  "experiments": [{"label": "fold0", "model": str(model)}]}))
    rows = generalisation.run_config(generalisation.load_config(config))
    points = {row["point"]: row for row in rows}
    kinds = ("int8", "float16", "tc", "ec-laplace", "ec-gaussian")
    assert {f"{base}-edge-{kind}" for base in ("pca", "pca-perm") for kind in kinds} <= set(points)
    assert all(0 <= e < float("inf") for row in rows for e in row["per_material_mapped"])
    names = points["pca-edge-tc"]["materials"]  # one family: the analytic held-out materials, in order
    with BrdfDataset(dataset) as data:
        pairs = [edge_slot_targets(table.values, table.mask) for table in map(data.table, map(data.index_of, names))]
    for n, (targets, weights) in enumerate(pairs):
        edge = weights > 0
        assert edge.any()
        np.testing.assert_array_equal(coded["pca-edge"][n][edge], targets[edge])
        np.testing.assert_array_equal(coded["pca-perm-edge"][n][edge], targets[edge])
        assert not coded["pca"][n][edge].any()


def test_config_errors_name_the_file(tmp_path: Path) -> None:
    from brdfcodec.report.generalisation import load_config

    path = tmp_path / "bad.json"
    path.write_text(json.dumps({"dataset": "x.h5", "experiments": [{"label": "a"}]}))
    with pytest.raises(ValueError, match="bad.json: each experiment"):
        load_config(path)
    path.write_text(json.dumps({"dataset": "x.h5", "experiments": [], "bugdets": [1]}))
    with pytest.raises(ValueError, match="unknown keys \\['bugdets'\\]"):
        load_config(path)
    path.write_text(json.dumps({"dataset": "x.h5", "experiments": [], "header_in_budget": "yes"}))
    with pytest.raises(ValueError, match="bad.json: 'header_in_budget' is true or false"):
        load_config(path)
    path.write_text(json.dumps({"dataset": "x.h5", "experiments": [], "header_in_budget": False}))
    assert load_config(path).header_in_budget is False and load_config(path).dataset == tmp_path / "x.h5"
    assert load_config(path).pca_edge_slots is False
    path.write_text(json.dumps({"dataset": "x.h5", "experiments": [], "pca_edge_slots": 1}))
    with pytest.raises(ValueError, match="bad.json: 'pca_edge_slots' is true or false"):
        load_config(path)
    path.write_text(json.dumps({"dataset": "x.h5", "experiments": [], "pca_edge_slots": True}))
    assert load_config(path).pca_edge_slots is True
    for step in (6, -1, True, "3"):
        path.write_text(json.dumps({"dataset": "x.h5", "experiments": [
            {"label": "a", "model": "m", "coded_mu_step": step}]}))
        with pytest.raises(ValueError, match="bad.json: an experiment's 'coded_mu_step' is an integer from 0 to 5"):
            load_config(path)
    for grids in ([], [3, 3], [3, 0], [2, 6], [True]):
        path.write_text(json.dumps({"dataset": "x.h5", "experiments": [
            {"label": "a", "model": "m", "coded_mu_step": grids}]}))
        with pytest.raises(ValueError, match="bad.json: an experiment's 'coded_mu_step' list holds distinct"):
            load_config(path)
    path.write_text(json.dumps({"dataset": "x.h5", "experiments": [{"label": "a", "model": "m", "coded_mu_step": 4},
                                                                   {"label": "b", "model": "m"},
                                                                   {"label": "c", "model": "m",
                                                                    "coded_mu_step": [3, 2]}]}))
    assert [e.coded_mu_step for e in load_config(path).experiments] == [4, None, (3, 2)]
    path.write_text(json.dumps({"dataset": "x.h5", "experiments": [{"label": "a", "model": "m",
                                                                    "short_references": False},
                                                                   {"label": "b", "model": "m"}]}))
    assert [e.short_references for e in load_config(path).experiments] == [False, True]
    path.write_text(json.dumps({"dataset": "x.h5", "experiments": [{"label": "a", "model": "m",
                                                                    "short_references": "no"}]}))
    with pytest.raises(ValueError, match="'short_references' is true or false"):
        load_config(path)
    path.write_text(json.dumps({"dataset": "x.h5", "experiments": [{"label": "a", "model": "m",
                                                                    "allocate": "library"},
                                                                   {"label": "b", "model": "m"}]}))
    assert [e.allocate for e in load_config(path).experiments] == ["library", "record"]
    path.write_text(json.dumps({"dataset": "x.h5", "experiments": [{"label": "a", "model": "m",
                                                                    "allocate": "files"}]}))
    with pytest.raises(ValueError, match="bad.json: an experiment's 'allocate' is 'record' or 'library'"):
        load_config(path)


@pytest.mark.slow  # trains, exports and encodes at seven rungs: > 10 s on 2 cores
def test_library_allocation_rows_keep_each_family_within_the_budget(fold_model: tuple[Path, Path],
                                                                     tmp_path: Path, monkeypatch) -> None:
    import brdfcodec
    from brdfcodec.cli.main import main
    from brdfcodec.report.rows import read_rows

    dataset, model = fold_model
    asked: list[dict[str, object]] = []
    real_encode = brdfcodec.encode

    def encode(*args: object, **options: object) -> bytes:
        asked.append(options)
        return real_encode(*args, **options)  # type: ignore[arg-type]

    monkeypatch.setattr(brdfcodec, "encode", encode)
    config = tmp_path / "rd.json"
    config.write_text(json.dumps({"dataset": str(dataset), "budgets": [32],
                                  "experiments": [{"label": "fold0", "model": str(model), "allocate": "library"}]}))
    assert main(["bench", "rd", "--config", str(config), "-o", str(tmp_path / "rows.jsonl"), "--quiet"]) == 0
    ours = [row for row in read_rows(tmp_path / "rows.jsonl") if row["point"] == "bvae"]
    assert ours and all(row["allocate"] == "library" and row["bytes_flag"] == 32 for row in ours)
    assert all(row["bytes_per_material"] <= 32 for row in ours)  # each family's records and header share
    assert len(asked) == 1 and asked[0]["allocate"] == "library" and asked[0]["bytes"] == 32  # one encode, no search
    assert asked[0]["groups"] == ["analytic"] * len(ours[0]["materials"])


def _row(group: str, point: str, budget: int, errors: list[float], size: float) -> dict:
    return {"schema": "brdfcodec.rows/1", "group": group, "family": "merl", "point": point, "budget_bytes": budget,
            "bytes_per_material": size, "per_material_mapped": errors}


def test_summary_pools_the_folds_of_a_group_and_takes_the_best_pca(tmp_path: Path) -> None:
    from brdfcodec.report.rows import rd_plot, summary_markdown

    rows = [_row("cv", "bvae", 16, [0.01, 0.03], 15.0), _row("cv", "bvae", 16, [0.05], 16.0),  # pooled 0.03
            _row("cv", "pca-int8", 16, [0.02, 0.04], 16), _row("cv", "pca-int8", 16, [0.06], 16),  # pooled 0.04
            _row("cv", "pca-perm-int8", 16, [0.035, 0.035], 16), _row("cv", "pca-perm-int8", 16, [0.035], 16)]
    table = summary_markdown(rows)
    assert "| 16 B | 0.0300 | 15.3 | 0.0350 | pca-perm-int8 | 16 | 0.0350 | yes |" in table, table
    # Worse than the best PCA, or over the budget: "no".
    rows[1]["per_material_mapped"] = [0.09]
    assert "| 16 B | 0.0433 |" in summary_markdown(rows) and "| no |" in summary_markdown(rows)
    rows[1]["per_material_mapped"], rows[1]["bytes_per_material"] = [0.05], 40.0
    assert "| no |" in summary_markdown(rows)
    assert rd_plot(rows, tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"
    # A budget the header's share leaves no room in has PCA rows only: said so, and the plot still draws.
    rows += [_row("cv", "pca-int8", 128, [0.01], 128)]
    assert ("| 128 B | — | — | | | | | no (no file fits: the header's share and the smallest records the model "
            "writes exceed the budget) |") in summary_markdown(rows)
    assert rd_plot(rows, tmp_path / "q.png").read_bytes()[:4] == b"\x89PNG"


def test_decode_time_plot_draws_every_timed_point_and_refuses_rows_without_times(tmp_path: Path) -> None:
    from brdfcodec.cli.main import main
    from brdfcodec.report.rd_markdown import write_decode_time_plot
    from brdfcodec.report.rows import write_rows

    rows = [_row("cv", "bvae", 16, [0.03], 15.0), _row("cv", "pca-tc", 16, [0.04], 16.0),
            _row("cv", "bvae", 64, [0.02], 60.0)]
    with pytest.raises(ValueError, match="no row has a decode time"):
        write_decode_time_plot(rows, tmp_path / "none.png")
    assert not (tmp_path / "none.png").exists()
    write_rows(tmp_path / "old.jsonl", rows)
    assert main(["bench", "table", str(tmp_path / "old.jsonl"), "--time-plot", str(tmp_path / "cli.png")]) == 1
    assert not (tmp_path / "cli.png").exists()
    for k, row in enumerate(rows):
        row.update(decode_ms_median=10.0 + k, decode_machine="CPU: test")
    assert write_decode_time_plot(rows, tmp_path / "t.png").read_bytes()[:4] == b"\x89PNG"


def test_a_library_is_over_its_budget_when_any_family_is() -> None:
    """The file within N per material is not enough: a family whose records fill the budget while another's do
    not exceeds N by a fraction of the header's share, and the runner lowers ``--bytes`` for it."""
    from brdfcodec.report.generalisation import bytes_over_budget

    records = {"a": 126, "b": 126, "c": 120, "d": 120}
    families = ["merl", "merl", "rgl", "rgl"]
    assert bytes_over_budget(records, 2.0, families, 128) == 0.0  # merl: 126 + 2
    assert bytes_over_budget(records, 2.5, families, 128) == 0.5  # merl over by 0.5, the file (125.5) within
    assert bytes_over_budget(records, 2.5, ["x"] * 4, 128) == -2.5  # one family: the file's mean
    assert bytes_over_budget({"a": 140, "b": 100}, 0.0, ["merl", "rgl"], 128) == 12.0


def _sizes(per_family: dict[str, Callable[[int], int]], families: list[str], share: float,
           flags: list[int]) -> Callable[[int], tuple[int, dict[str, int], float]]:
    """A stand-in for the runner's encode: each material's record bytes a function of ``--bytes`` per family, the
    header's share fixed; the flags tried are appended to ``flags``."""

    def encoded(flag: int) -> tuple[int, dict[str, int], float]:
        flags.append(flag)
        return flag, {f"m{i}": per_family[family](flag) for i, family in enumerate(families)}, share

    return encoded


def test_the_bytes_flag_search_moves_up_while_records_grow_and_down_when_over() -> None:
    from brdfcodec.report.generalisation import search_bytes_flag

    families = ["merl", "merl", "rgl"]
    filled = {"merl": lambda flag: flag, "rgl": lambda flag: flag}  # records fill --bytes
    flags: list[int] = []  # the header's share (3) was estimated high (6): the search moves up to 13
    flag, result, records, share = search_bytes_flag(_sizes(filled, families, 3.0, flags), 10, 16, families)
    assert (flag, result, share) == (13, 13, 3.0) and records["m0"] == 13 and flags == [10, 13]
    flags.clear()  # estimated low: down by the excess, to 13
    assert search_bytes_flag(_sizes(filled, families, 3.0, flags), 16, 16, families)[0] == 13
    assert flags == [16, 13]
    flags.clear()  # one family over while the file is within: lowered for that family
    uneven = {"merl": lambda flag: flag + 2, "rgl": lambda flag: flag - 4}
    assert search_bytes_flag(_sizes(uneven, families, 3.0, flags), 13, 16, families)[0] == 11
    assert flags == [13, 11]


def test_the_bytes_flag_search_stops_when_records_stop_growing_and_keeps_the_largest_fit() -> None:
    from brdfcodec.report.generalisation import search_bytes_flag

    families = ["merl", "rgl"]
    flags: list[int] = []
    full = {"merl": lambda flag: min(flag, 10), "rgl": lambda flag: min(flag, 10)}  # records full at 10 bytes
    flag, _, records, _ = search_bytes_flag(_sizes(full, families, 2.0, flags), 8, 128, families)
    # 8 → 126 (the spare), grown 8 → 10 bytes: one more, to N; not grown there: no fourth try
    assert flags == [8, 126, 128] and flag == 128 and records == {"m0": 10, "m1": 10}
    flags.clear()
    stalled = {"merl": lambda flag: min(flag, 10), "rgl": lambda flag: min(flag, 10)}
    assert search_bytes_flag(_sizes(stalled, families, 2.0, flags), 10, 128, families)[0] == 126
    assert flags == [10, 126]  # full from the start: the larger flag made no larger records, no third try
    flags.clear()  # never within: the flag falls by the excess and the last one tried is returned, not a next one
    over = {"merl": lambda flag: max(flag, 8) + 10, "rgl": lambda flag: max(flag, 8) + 10}  # at least 18 bytes
    flag, result, _, _ = search_bytes_flag(_sizes(over, families, 0.0, flags), 12, 16, families, tries=3)
    assert flags == [12, 6, 4] and (flag, result) == (4, 4)
    flags.clear()  # one try only (a single-material file with the header on top)
    assert search_bytes_flag(_sizes(full, families, 2.0, flags), 8, 16, families, tries=1)[0] == 8
    assert flags == [8]


def test_a_flag_below_the_smallest_record_ends_the_search() -> None:
    """An encode that refuses a flag (below the smallest record a material can take, ``RateTargetError``) ends the
    search with the last library encoded; refused at the first flag, the error reaches the caller, which leaves the
    budget without a point."""
    from brdfcodec.errors import RateTargetError
    from brdfcodec.report.generalisation import search_bytes_flag

    families = ["merl", "rgl"]
    flags: list[int] = []
    sizes = _sizes({"merl": lambda flag: flag + 4, "rgl": lambda flag: flag + 4}, families, 0.0, flags)

    def encoded(flag: int) -> tuple[int, dict[str, int], float]:
        if flag < 10:
            flags.append(flag)
            raise RateTargetError(f"m0: {flag} bytes is below the base record's 10 bytes")
        return sizes(flag)

    flag, result, records, _ = search_bytes_flag(encoded, 12, 12, families)  # over by 4 at 12: down to 8, refused
    assert flags == [12, 8] and (flag, result) == (12, 12) and records["m0"] == 16
    with pytest.raises(RateTargetError):
        search_bytes_flag(encoded, 9, 12, families)


def test_rd_rows_name_the_commit_the_run_started_at(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """A run takes an hour: a commit made meanwhile is not the code it measured."""
    import argparse

    from brdfcodec.cli import bench_command
    from brdfcodec.report import generalisation, rows

    config = tmp_path / "config.json"
    config.write_text(json.dumps({"dataset": "data.h5", "experiments": [{"label": "x", "model": "m"}]}))
    checkout = {"commit": "started-at"}

    def run_config(config, progress=None):  # noqa: ANN001, ANN202 - the run, during which a commit is made
        checkout["commit"] = "written-at"
        return [{"point": "bvae", "budget_bytes": 16, "family": "merl", "group": "x", "experiment": "x",
                 "mapped_relae_mean": 0.1}]

    monkeypatch.setattr(rows, "current_commit", lambda: checkout["commit"])
    monkeypatch.setattr(generalisation, "run_config", run_config)
    monkeypatch.setattr(rows, "summary_markdown", lambda rows: "")
    output = tmp_path / "rows.jsonl"
    assert bench_command.run_rd(argparse.Namespace(config=config, output=output, quiet=True, budgets=None)) == 0
    written = [json.loads(line) for line in output.read_text().splitlines()]
    assert [row["commit"] for row in written] == ["started-at"]


def test_budgets_option_replaces_the_configurations_and_refuses_bad_lists(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """``bvae bench rd --budgets 32,64`` runs those budgets only; a list that is not positive integers exits 2
    with a message naming the option, before any work."""
    from brdfcodec.cli import bench_command
    from brdfcodec.cli.main import main
    from brdfcodec.report import generalisation, rows

    config = tmp_path / "config.json"
    config.write_text(json.dumps({"dataset": "data.h5", "budgets": [16, 32, 64, 128],
                                  "experiments": [{"label": "x", "model": "m"}]}))
    ran: list[tuple[int, ...]] = []

    def run_config(config, progress=None):  # noqa: ANN001, ANN202
        ran.append(config.budgets)
        return [{"point": "bvae", "budget_bytes": b, "family": "merl", "group": "x", "experiment": "x",
                 "mapped_relae_mean": 0.1} for b in config.budgets]

    monkeypatch.setattr(generalisation, "run_config", run_config)
    monkeypatch.setattr(rows, "current_commit", lambda: "abc")
    monkeypatch.setattr(rows, "summary_markdown", lambda rows: "")
    output = tmp_path / "rows.jsonl"
    assert main(["bench", "rd", "--config", str(config), "-o", str(output), "--quiet", "--budgets", "32,64"]) == 0
    assert ran == [(32, 64)]
    assert [json.loads(line)["budget_bytes"] for line in output.read_text().splitlines()] == [32, 64]
    assert main(["bench", "rd", "--config", str(config), "-o", str(output), "--quiet"]) == 0
    assert ran[-1] == (16, 32, 64, 128)
    capsys.readouterr()
    for bad in ("0,32", "32,x", ""):
        assert main(["bench", "rd", "--config", str(config), "-o", str(tmp_path / "bad.jsonl"), "--budgets",
                     bad]) == 2
        assert "--budgets" in capsys.readouterr().err
    assert len(ran) == 2 and not (tmp_path / "bad.jsonl").exists()
    assert bench_command._budget_list("8") == (8,)
