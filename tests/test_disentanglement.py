"""The disentanglement benchmark (issue 41, part 1): factor materials, MIG, DCI, the command.

MIG and DCI are checked on worked examples whose answers are known: a code
that copies the factors (plus noise dimensions) is disentangled (MIG near 1,
D = C = I = 1), a code that rotates pairs of factors into each other is not
(MIG near 0, D and C near 1/2), and a code independent of the factors scores
near 0 in MIG and informativeness.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from brdfcodec.datasets.analytic import FACTOR_NAMES, AnalyticBRDF, factor_material, sample_factor_materials
from brdfcodec.report.disentanglement import (
    DisentanglementInputError,
    boosted_stumps,
    dci,
    default_bins,
    discretise,
    mig,
    mutual_information_matrix,
    score_code,
)

N = 1000


@pytest.fixture(scope="module")
def factors() -> np.ndarray:
    return np.random.default_rng(1).random((N, 4))


def noise(columns: int, seed: int = 2) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(N, columns))


def rotation_of_pairs() -> np.ndarray:
    c = s = np.sqrt(0.5)
    rotation = np.zeros((4, 4))
    rotation[:2, :2] = rotation[2:, 2:] = [[c, -s], [s, c]]
    return rotation


def test_a_code_that_copies_the_factors_is_disentangled(factors: np.ndarray) -> None:
    code = np.concatenate([factors[:, [2, 0, 3, 1]], noise(4)], axis=1)  # permuted, plus 4 unused dimensions
    scores = score_code(code, factors, list("abcd"))
    assert scores.mig > 0.9
    assert scores.disentanglement > 0.99 and scores.completeness > 0.99 and scores.informativeness > 0.99
    assert scores.dominant_factor[:4] == ["c", "a", "d", "b"]
    assert min(scores.dominant_share[:4]) > 0.99
    assert max(scores.dimension_weight[4:]) < 0.01


def test_scores_do_not_change_under_a_monotone_reparametrisation(factors: np.ndarray) -> None:
    code = np.concatenate([factors, noise(2)], axis=1)
    bent = code.copy()
    bent[:, :4] = np.exp(4 * factors) - 3 * factors  # increasing in each factor
    assert mig(bent, factors)[0] == pytest.approx(mig(code, factors)[0], abs=1e-12)


def test_a_rotated_code_is_not_disentangled(factors: np.ndarray) -> None:
    code = (factors - 0.5) @ rotation_of_pairs().T
    scores = score_code(code, factors, list("abcd"))
    assert scores.mig < 0.1
    assert 0.4 < scores.disentanglement < 0.6 and 0.4 < scores.completeness < 0.6
    assert scores.informativeness > 0.9  # all the information is there, mixed


def test_a_code_independent_of_the_factors_scores_near_zero(factors: np.ndarray) -> None:
    scores = score_code(noise(8, seed=5), factors, list("abcd"))
    assert scores.mig < 0.03
    assert scores.informativeness < 0.05
    assert scores.disentanglement < 0.3 and scores.completeness < 0.3


def test_mutual_information_of_a_copy_is_the_entropy(factors: np.ndarray) -> None:
    mi, entropy = mutual_information_matrix(factors, factors, bins=10)
    np.testing.assert_allclose(np.diag(mi), entropy, rtol=1e-12)
    np.testing.assert_allclose(entropy, np.log(10), rtol=1e-12)  # equal-frequency bins of N = 1000
    assert mi[0, 1] < 0.05


def test_discretise_uses_ranks_and_keeps_constant_columns_in_one_bin() -> None:
    values = np.array([[3.0, 1.0], [1.0, 1.0], [2.0, 1.0], [10.0, 1.0]])
    np.testing.assert_array_equal(discretise(values, 2), [[1, 0], [0, 0], [0, 0], [1, 0]])
    assert default_bins(300) == 9 and default_bins(10_000) == 20 and default_bins(4) == 2


def test_boosted_stumps_fit_a_step_and_credit_its_input() -> None:
    rng = np.random.default_rng(0)
    x = rng.random((400, 3))
    y = np.where(x[:, 1] > 0.5, 1.0, -1.0)
    model = boosted_stumps(x, y, rounds=100)
    assert np.abs(model.predict(x) - y).mean() < 0.05
    assert model.importance.argmax() == 1 and model.importance[[0, 2]].sum() < 0.01 * model.importance[1]


def test_dci_needs_samples_on_both_sides_and_matching_shapes(factors: np.ndarray) -> None:
    with pytest.raises(DisentanglementInputError):
        dci(factors[:12], factors[:12], train_fraction=0.95)
    with pytest.raises(DisentanglementInputError):
        score_code(factors, factors[:-1], list("abcd"))
    with pytest.raises(DisentanglementInputError):
        score_code(factors, factors, list("abc"))
    with pytest.raises(DisentanglementInputError):
        mig(np.full((20, 2), np.nan), factors[:20])


# ------------------------------------------------------------------------------------------ the materials


def test_factor_materials_are_reproducible_and_their_factors_independent() -> None:
    drawn = sample_factor_materials(400, seed=3)
    assert drawn.factors.shape == (400, len(FACTOR_NAMES)) and drawn.names == FACTOR_NAMES
    assert drawn.factors.min() >= 0 and drawn.factors.max() <= 1
    correlation = np.corrcoef(drawn.factors.T) - np.eye(len(FACTOR_NAMES))
    assert np.abs(correlation).max() < 0.15
    again = sample_factor_materials(5, seed=3)
    assert again.materials == drawn.materials[:5]
    assert sample_factor_materials(5, seed=4).materials != again.materials


def test_each_factor_moves_its_own_property() -> None:
    middle = np.full(len(FACTOR_NAMES), 0.5)

    def at(name: str, value: float) -> AnalyticBRDF:
        values = middle.copy()
        values[FACTOR_NAMES.index(name)] = value
        return factor_material(values)

    assert np.mean(at("albedo", 1).diffuse) > 10 * np.mean(at("albedo", 0).diffuse)
    assert at("hue", 0).diffuse[0] > at("hue", 0).diffuse[2] and at("hue", 1).diffuse[2] > at("hue", 1).diffuse[0]
    assert at("roughness", 1).roughness > 10 * at("roughness", 0).roughness
    assert at("specular", 1).specular[0] > at("specular", 0).specular[0]
    assert at("grazing", 0).grazing == 0 and at("sheen", 1).sheen == 0.5
    metal = at("metallic", 1)
    assert metal.diffuse == (0.0, 0.0, 0.0) and metal.specular != at("metallic", 0).specular
    with pytest.raises(ValueError):
        factor_material(np.full(len(FACTOR_NAMES), 1.5))


def test_the_kept_slice_input_equals_the_full_tables() -> None:
    from brdfcodec.representation import network_input_from_table

    material = AnalyticBRDF("m", (0.3, 0.2, 0.1), (0.9, 0.5, 0.2), 0.05, grazing=0.3, sheen=0.4)
    inputs, mask = material.kept_network_input()
    want_inputs, want_mask = network_input_from_table(material.to_merl().values)
    np.testing.assert_array_equal(mask, want_mask)
    np.testing.assert_allclose(inputs, want_inputs, rtol=1e-6, atol=1e-6)


def test_grazing_and_sheen_change_only_what_they_should() -> None:
    wi = np.array([[np.sin(1.4), 0.0, np.cos(1.4)]])
    wo = np.array([[-np.sin(1.4), 0.0, np.cos(1.4)]])  # mirror pair near grazing
    plain = AnalyticBRDF("p", 0.2, 0.04, 0.3)
    assert AnalyticBRDF("g", 0.2, 0.04, 0.3, grazing=0.0).evaluate(wi, wo)[0, 0] < plain.evaluate(wi, wo)[0, 0]
    sheen = AnalyticBRDF("s", 0.2, 0.04, 0.3, sheen=0.5).evaluate(wi, wo)[0, 0] - plain.evaluate(wi, wo)[0, 0]
    assert sheen == pytest.approx(0.5 / np.pi * (1 - np.cos(1.4)) ** 5)
    normal = np.array([[0.0, 0.0, 1.0]])
    assert AnalyticBRDF("s", 0.2, 0.04, 0.3, sheen=0.5).evaluate(normal, normal)[0, 0] == pytest.approx(
        plain.evaluate(normal, normal)[0, 0])
    with pytest.raises(ValueError):
        AnalyticBRDF("x", grazing=1.5)


# ------------------------------------------------------------------------------------------ the command


@pytest.mark.slow
def test_bvae_model_disentanglement_writes_stamped_rows(tiny_model_folder: Path, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    from brdfcodec.cli.main import main
    from brdfcodec.report.rows import read_rows

    out = tmp_path / "rows.jsonl"
    assert main(["model", "disentanglement", str(tiny_model_folder), "--materials", "30", "--seed", "2",
                 "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "MIG" in printed and "tiny-test-model" in printed and "PCA-8" in printed
    rows = read_rows(out)
    assert [row["model"] for row in rows] == ["tiny-test-model", "PCA-8", "PCA-8 aligned"]
    pca, aligned = rows[1], rows[2]
    assert aligned["code"] == "pca-aligned" and aligned["base_relae_kept_mapped"] == pca["base_relae_kept_mapped"]
    assert aligned["mig"] != pca["mig"]  # the same code, turned
    for row in rows:
        assert row["study"] == "disentanglement" and row["materials"] == 30 and row["seed"] == 2
        assert 0 <= row["mig"] <= 1 and 0 <= row["dci_informativeness"] <= 1
        assert len(row["dominant_factor"]) == row["latent_dim"] == 8
        assert set(row["dominant_factor"]) <= set(FACTOR_NAMES)
        assert row["base_relae_kept_mapped"] > 0
        json.dumps(row, allow_nan=False)
    assert main(["model", "disentanglement", "--materials", "5"]) == 2
    assert main(["model", "disentanglement", str(tiny_model_folder), "--materials", "30", "-o", str(out)]) == 1
