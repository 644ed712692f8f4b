"""Issue 12 item 6: a model measured per family and split, beside PCA-8/16 of its own training materials."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from brdfcodec.datasets.hdf5 import build_dataset
from brdfcodec.datasets.sources import analytic_sources


@pytest.fixture(scope="module")
def analytic_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("families") / "analytic.h5"
    sources = analytic_sources(["white-matte", "gold", "green-satin"], random_count=9, seed=4)  # names no proxy has
    build_dataset(out, sources, source_kind="analytic", description="analytic test materials", progress=False)
    return out


@pytest.mark.slow
def test_rows_per_family_and_split(analytic_dataset: Path) -> None:
    from brdfcodec.training.family_report import evaluate_by_family, family_table

    rows = evaluate_by_family(None, analytic_dataset)
    # The shipped model was trained on none of these materials: every one is held out, in the one family.
    assert [(r.family, r.split, r.count) for r in rows] == [("analytic", "held-out", 12)]
    row = rows[0]
    for value in (row.mapped, row.linear, row.delta_e_itp, row.pca8_mapped):
        assert 0 < value < 5
    assert row.pca16_mapped <= row.pca8_mapped + 1e-9  # more components, never worse in least squares terms
    # The baselines never see the materials the dataset holds out: fitted on its training materials, PCA
    # reproduces those up to the slice interpolation but not the held-out ones, which lift the mean above it.
    import numpy as np

    from brdfcodec.datasets.hdf5 import BrdfDataset
    from brdfcodec.representation import table_from_network_output
    from brdfcodec.representation.metrics import relae_mapped

    with BrdfDataset(analytic_dataset) as dataset:
        assert len(dataset.indices("validation")) >= 1
        floor = np.mean([relae_mapped(dataset.table(i).values,
                                      table_from_network_output(dataset.inputs([i])[0]).astype(np.float64),
                                      dataset.table(i).mask).overall for i in range(len(dataset))])
    assert row.pca16_mapped > floor + 2e-3
    assert "| analytic | held-out | 12 |" in "\n".join(family_table(rows))


@pytest.mark.slow
def test_cli_evaluate_stores_into_a_copy_of_the_model(analytic_dataset: Path, tmp_path: Path, capsys) -> None:
    import shutil

    from brdfcodec.cli.main import main
    from brdfcodec.models.registry import default_model_folder
    from brdfcodec.training import family_report

    folder = tmp_path / "model"
    shutil.copytree(default_model_folder(), folder)
    original = family_report.evaluate_by_family
    family_report.evaluate_by_family = lambda *a, **k: original(*a, **{**k, "limit": 1})  # type: ignore[assignment]
    try:
        assert main(["model", "evaluate", str(folder), "--dataset", str(analytic_dataset), "--store"]) == 0
    finally:
        family_report.evaluate_by_family = original  # type: ignore[assignment]
    assert "| analytic | held-out | 1 |" in capsys.readouterr().out
    stored = json.loads((folder / "model.json").read_text())["info"]["by_family"]
    assert stored["effort"] == 0 and stored["rows"][0]["family"] == "analytic"
    assert "## Per measurement family" in (folder / "MODEL_CARD.md").read_text()


@pytest.mark.slow
def test_mu_on_a_grid_is_decoded_as_a_coded_mu_stores_it_and_its_bytes_are_counted(analytic_dataset: Path) -> None:
    from brdfcodec.training.family_report import evaluate_by_family

    exact, fine, coarse = (evaluate_by_family(None, analytic_dataset, limit=3, mu_grid=g)[0] for g in (None, 5, 1))
    assert exact.mu_grid is None and exact.mu_bytes is None
    assert (fine.mu_grid, coarse.mu_grid) == (5, 1)
    # D = 8 dimensions of about unit spread: some 2.5 bits each on the grid 1/2, 6.5 or more on 1/32.
    assert 1.5 < coarse.mu_bytes < fine.mu_bytes < 16
    # A fine grid decodes as μ itself does; the coarse one moves the decode.
    assert fine.mapped == pytest.approx(exact.mapped, abs=2e-3)
    assert abs(coarse.mapped - exact.mapped) > abs(fine.mapped - exact.mapped)
    # The shipped model saw none of these materials: no prior for μ can be fitted to its training materials.
    assert coarse.mu_bytes_fitted is None and coarse.mu_prior_codes is None
    with pytest.raises(ValueError, match="mu_grid"):
        evaluate_by_family(None, analytic_dataset, limit=1, mu_grid=6)


def test_mu_s_bytes_under_priors_fitted_to_the_training_materials() -> None:
    """Per-dimension prior codes are fitted to the μ of the rows the model trained on, and only to those; every
    row's μ is priced under them: a dimension the training materials leave at 0 costs almost nothing, a wide one
    about what the unit prior charges."""
    import json

    import numpy as np

    from brdfcodec.layers.coded_basis import coded_mu_codes, encode_integers, fit_prior_codes
    from brdfcodec.training.family_report import _group, _price_under_fitted_prior

    rng = np.random.default_rng(0)

    def row(split: str) -> dict:
        # held-out materials use dimension 2, which the training ones leave at 0: a fit that saw them would widen it
        used = 0 if split == "train" else round(rng.normal() * 4)
        q = np.array([round(rng.normal() * 4), 0, used, round(rng.normal() * 4)], dtype=np.int64)
        return {"split": split, "family": "f", "mu_integers": q, "name": f"m{rng.integers(1 << 30)}",
                "mu_bytes": float(len(encode_integers(q, coded_mu_codes(2, 4)))),
                **{key: 0.1 for key in ("model_mapped", "model_linear", "model_itp", "pca8_mapped", "pca16_mapped",
                                        "pca8_itp", "pca16_itp")}}

    train = [row("train") for _ in range(40)]
    expected = fit_prior_codes(np.stack([r["mu_integers"] for r in train]))
    rows = train + [row("held-out") for _ in range(10)]
    codes = _price_under_fitted_prior(rows)
    assert codes == tuple(expected)
    assert "mu_integers" not in rows[0]
    assert codes[1] == codes[2] == -80 and codes[0] > 0 and codes[3] > 0
    trained = [r for r in rows if r["split"] == "train"]
    assert np.mean([r["mu_bytes_fitted"] for r in trained]) < np.mean([r["mu_bytes"] for r in trained]) - 0.5
    # Grouped per family and split, as `bvae model evaluate --json` prints them.
    grouped = {r.split: r for r in _group(rows, 2, codes)}
    assert grouped["train"].mu_prior_codes == codes and grouped["held-out"].mu_bytes_fitted > 0
    assert json.loads(json.dumps(grouped["train"].as_dict()))["mu_prior_codes"] == list(codes)
    # No training material: nothing to fit, no fitted bytes.
    alone = [row("held-out")]
    assert _price_under_fitted_prior(alone) is None and alone[0]["mu_bytes_fitted"] is None
    assert _group(alone, 2, None)[0].mu_bytes_fitted is None


def test_cli_refuses_to_store_a_table_of_mu_on_a_grid(analytic_dataset: Path, capsys) -> None:
    from brdfcodec.cli.main import main

    assert main(["model", "evaluate", "--dataset", str(analytic_dataset), "--mu-grid", "2", "--store"]) != 0
    assert "--mu-grid" in capsys.readouterr().err
