"""The size / error / time report: operating points, records, Markdown and plots."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from brdfcodec.datasets.hdf5 import build_dataset
from brdfcodec.datasets.sources import analytic_sources
from brdfcodec.report.evaluate import evaluate_dataset, summarise
from brdfcodec.report.output import write_report
from brdfcodec.report.points import BvaeCodec, KeptSlices, Pca, RawTable, ZstdTable


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("report") / "data.h5"
    build_dataset(path, analytic_sources(["gold", "red-plastic", "chrome"]), source_kind="analytic",
                  description="analytic test materials", validation_fraction=0.34, progress=False)
    return path


@pytest.mark.slow  # > 10 s on 2 cores
def test_report_records_and_files(small_dataset: Path, tmp_path: Path) -> None:
    from brdfcodec.datasets.hdf5 import BrdfDataset

    with BrdfDataset(small_dataset) as dataset:
        train_inputs = dataset.inputs(dataset.indices("train"))
    points = [BvaeCodec("float32"), Pca(train_inputs, 1), KeptSlices(), RawTable("float32"), ZstdTable("float32")]
    points, rows, data = evaluate_dataset(small_dataset, points=points, progress=False)
    assert len(rows) == 5 * 3 and data["materials"] == 3
    records = {r["name"]: r for r in summarise(points, rows, data)}
    raw = records["raw-float32"]
    assert raw["bytes_per_material"] == 3 * 90 * 90 * 180 * 4 and raw["shared_bytes"] == 0
    assert raw["errors"]["all"]["relae_mapped"]["worst"] < 1e-6
    assert records["zstd-float32"]["errors"]["all"]["relae_mapped"]["worst"] < 1e-6
    assert records["zstd-float32"]["bytes_per_material"] < raw["bytes_per_material"]
    assert 0 < records["kept-slices"]["errors"]["all"]["relae_mapped"]["mean"] < 0.05
    bvae = next(r for name, r in records.items() if name.startswith("bvae"))
    assert bvae["bytes_per_material"] < 1000 and bvae["shared_bytes"] > 1e6
    for record in records.values():
        for key in ("device", "torch", "brdfcodec", "encode_ms_median", "decode_ms_median", "data"):
            assert key in record
        stats = record["errors"]["all"]
        assert {"mean", "median", "p90", "worst", "worst_material"} <= stats["relae_mapped"].keys()
        assert np.isfinite(stats["delta_e_itp"]["mean"]) and np.isfinite(stats["log_domain_mae"]["mean"])
    written = write_report(tmp_path / "out", list(records.values()), rows)
    assert {p.name for p in written} == {"report.jsonl", "materials.jsonl", "report.md", "relae_vs_decode_time.png",
                                         "relae_vs_bytes.png", "rd_relae_mapped.png", "rd_relae_linear.png",
                                         "rd_delta_e_itp.png"}
    lines = (tmp_path / "out" / "report.jsonl").read_text().splitlines()
    assert [json.loads(line)["name"] for line in lines] == list(records)
    table = (tmp_path / "out" / "report.md").read_text()
    assert "analytic test materials" in table and table.count("\n| ") >= 6
    assert (tmp_path / "out" / "relae_vs_bytes.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_rate_distortion_points_are_held_out_only_and_meet_their_budgets(small_dataset: Path, tmp_path: Path) -> None:
    from brdfcodec.datasets.hdf5 import BrdfDataset
    from brdfcodec.models.pca import fit_pca
    from brdfcodec.report.rd_markdown import rd_markdown
    from brdfcodec.report.rd_points import DctSlices, LayeredBvae, PcaPacked, ZstdSlices

    with BrdfDataset(small_dataset) as dataset:
        train_inputs = dataset.inputs(dataset.indices("train"))
        held = len(dataset.indices("validation"))
    basis = fit_pca(train_inputs, 2)
    points = [LayeredBvae(bytes_budget=2048), PcaPacked(basis, 2, "int8"), PcaPacked(basis, 2, "float16"),
              ZstdSlices(0.05), DctSlices(0.5)]
    points, rows, data = evaluate_dataset(small_dataset, points=points, progress=False)
    assert len(rows) == len(points) * held and all(r["split"] == "validation" for r in rows)
    records = {r["name"]: r for r in summarise(points, rows, data)}
    assert records["pca-2-int8"]["bytes_per_material"] == 4 and records["pca-2-float16"]["bytes_per_material"] == 4
    layered = records["bvae-layered@2KB"]
    assert 32 < layered["bytes_per_material"] <= 2048 and layered["family"] == "bvae-layered"
    assert "train" not in layered["errors"]
    text = rd_markdown(list(records.values()))
    assert "| 1 KB |" in text and "bvae-layered@2KB" in text



@pytest.mark.slow
def test_the_report_compares_with_pca_of_colour_permuted_training_materials() -> None:
    from brdfcodec.layers.basis import with_colour_permutations
    from brdfcodec.models.pca import fit_pca
    from brdfcodec.report.points import Material
    from brdfcodec.report.rd_points import PcaPacked, rate_distortion_points
    from brdfcodec.representation import table_from_network_output

    rng = np.random.default_rng(5)
    train = rng.uniform(0.0, 1.0, size=(3, 63, 90, 90)).astype(np.float32)
    points = {p.name: p for p in rate_distortion_points(train)}
    # 3 materials in 6 colour orders span 14 dimensions: 8 coefficients as float16 and 14 as int8, nothing larger.
    perm = sorted(name for name in points if name.startswith("pca-perm-"))
    assert perm == ["pca-perm-14-int8", "pca-perm-8-float16"]
    assert points["pca-perm-14-int8"].family == "pca-perm-int8"
    assert "colour orders" in points["pca-perm-14-int8"].description
    points["pca-2-float16"] = PcaPacked(fit_pca(train, 2), 2, "float16")  # of the materials as measured
    points["pca-perm-14-float16"] = PcaPacked(points["pca-perm-14-int8"].basis, 14, "float16", "perm")
    # A training material with its colours exchanged is in the permuted PCA's span, not in the plain one's.
    swapped = with_colour_permutations(train)[5 * 3]  # order (B, G, R) of the first material
    truth = table_from_network_output(swapped)
    material = Material("swapped", truth.astype(np.float64), np.ones(truth.shape, dtype=bool), swapped, "validation")

    def worst_error(name: str) -> float:
        point = points[name]
        return float(np.abs(point.decode(point.encode(material)) - truth).max() / np.abs(truth).max())

    assert worst_error("pca-perm-14-float16") < 0.01
    assert worst_error("pca-2-float16") > 0.05


def test_plot_styles_tell_twenty_curves_apart_by_colour_and_more_by_line_style() -> None:
    from brdfcodec.report.styles import distinct_colour_index, distinct_line_style

    first = [distinct_colour_index(k) for k in range(20)]
    assert sorted(first) == list(range(20))  # every tab20 colour once
    assert first[:10] == list(range(0, 20, 2))  # dark shades first
    styles = {(distinct_colour_index(k), distinct_line_style(k)) for k in range(80)}
    assert len(styles) == 80
    with pytest.raises(ValueError, match="curve index"):
        distinct_colour_index(-1)


def test_rate_distortion_plot_draws_every_family_in_its_own_style(monkeypatch: pytest.MonkeyPatch,
                                                                  tmp_path: Path) -> None:
    import matplotlib.pyplot as plt

    from brdfcodec.report.rd_markdown import write_rd_plots

    families = [f"family-{k:02d}" for k in range(23)]
    records = [{"name": f, "family": f, "bytes_per_material": 2.0**b, "lossless": False,
                "data": {"description": "test"},
                "errors": {"validation": {m: {"mean": 0.1 / (b + 1)} for m in
                                          ("relae_mapped", "relae_linear", "delta_e_itp")}}}
               for f in families for b in range(3)]
    figures = []
    monkeypatch.setattr(plt, "close", figures.append)
    write_rd_plots(records, tmp_path)
    lines = figures[0].axes[0].get_lines()
    drawn = [line for line in lines if line.get_label() in families]
    assert len(drawn) == len(families)
    assert len({(line.get_color(), line.get_linestyle()) for line in drawn}) == len(families)


@pytest.mark.slow
def test_the_report_has_projected_base_points_up_to_256_bytes() -> None:
    from brdfcodec.report.rd_points import LayeredBvae, rate_distortion_points

    train = np.random.default_rng(6).uniform(0.0, 1.0, size=(3, 63, 90, 90)).astype(np.float32)
    points = rate_distortion_points(train)
    for family, way in (("bvae-projected", "always"), ("bvae-unprojected", "never")):
        fixed = [p for p in points if p.name.startswith(f"{family}@")]
        assert [p.name for p in fixed] == [f"{family}@{n}B" for n in (16, 32, 64, 128, 256)]
        assert all(p.family == family and p.encoder.options.project_base == way for p in fixed)
    layered = [p for p in points if p.family == "bvae-layered"]
    assert layered and all(p.encoder.options.project_base == "auto" for p in layered)  # the default
    with pytest.raises(ValueError, match="size budget"):
        LayeredBvae(max_relae=0.02, project_base="always")
