"""Plausibility of traversal decodes (brdfcodec.edit.plausibility, ``bvae model plausibility``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from brdfcodec.cli import main
from brdfcodec.conventions import MERL_COLOR_SCALE, NETWORK_INPUT_SHAPE
from brdfcodec.edit.plausibility import (
    PlausibilityCriteria,
    inverted_cells,
    measure_plausibility,
    new_holes,
    plausible_range,
    specular_deficit,
    white_sky_albedo,
)
from brdfcodec.edit.plausibility import _invalid_counts as invalid_counts
from brdfcodec.models.output_paths import decompose_output
from brdfcodec.representation import to_network_layout
from brdfcodec.representation.mapping import map_values

GREEN_SLOT_10 = 21 + 10  # green at kept slot 10 (φd bin 90)


def peaked(peak: float = 1.0, flank: float = 0.5, floor: float = 0.3) -> np.ndarray:
    """Mapped slices with a specular peak: θh 0–1 at ``peak``, θh 2–6 at ``flank``, the rest at ``floor``."""
    mapped = np.full(NETWORK_INPUT_SHAPE, floor, dtype=np.float32)
    mapped[:, 0:2] = peak
    mapped[:, 2:7] = flank
    return mapped


def test_a_peak_is_not_inverted_and_a_flank_above_it_is() -> None:
    assert not inverted_cells(peaked()).any()
    assert float(np.nanmax(specular_deficit(peaked()))) == pytest.approx(-0.5)
    flat = peaked(0.5, 0.5)  # a diffuse material: no peak, no inversion
    assert not inverted_cells(flat).any()
    dent = peaked()
    dent[GREEN_SLOT_10, 0:2, 10] = 0.2  # one cell: peak 0.3 below its flank
    cells = inverted_cells(dent)
    assert cells.sum() == 1 and cells[1, 10, 10]
    assert specular_deficit(dent)[1, 10, 10] == pytest.approx(0.3)


def test_inversion_tolerance_and_the_peak_rows() -> None:
    small = peaked()
    small[GREEN_SLOT_10, 0:2, 10] = 0.45  # 0.05 below the flank: within τ = 0.1
    assert not inverted_cells(small).any()
    assert inverted_cells(small, tolerance=0.01).sum() == 1
    one_row = peaked()
    one_row[GREEN_SLOT_10, 0, 10] = 0.0  # θh bin 1 still holds the peak: not inverted
    assert not inverted_cells(one_row).any()
    flank_row = peaked()
    flank_row[GREEN_SLOT_10, 6, 10] = 1.3  # θh bin 6 is in the flank
    assert inverted_cells(flank_row).sum() == 1
    outside = peaked()
    outside[GREEN_SLOT_10, 7, 10] = 1.3  # θh bin 7 is not
    assert not inverted_cells(outside).any()


def test_non_finite_peaks_count_as_inverted() -> None:
    broken = peaked()
    broken[GREEN_SLOT_10, 0, 10] = np.nan
    assert inverted_cells(broken).sum() == 1


def test_a_pit_wider_than_the_peak_rows_is_seen_by_pits_only() -> None:
    from brdfcodec.edit.plausibility import pit_cells, pit_depth

    mapped = np.full((63, 90, 90), 0.6, dtype=np.float32)
    mapped[GREEN_SLOT_10, 0:10, 10] = 0.0  # a dark disc out to θh bin 9 inside a lit rim: the dot a sheet shows
    assert not inverted_cells(mapped).any()  # bins 0–1 against 4–6: both dark
    assert not new_holes(np.full_like(mapped, 0.6), mapped).any()  # no lit flank at bins 4–6
    depth = pit_depth(mapped)
    assert float(depth[1, 10, 10]) == pytest.approx(0.6) and pit_cells(mapped)[1, 10, 10]
    others = np.delete(depth.reshape(-1), np.ravel_multi_index((1, 10, 10), depth.shape))
    assert int(pit_cells(mapped).sum()) == 1 and float(np.nanmax(others)) == 0.0


def test_invalid_values_are_counted_above_the_horizon_only() -> None:
    good = peaked()[None]
    assert invalid_counts(good).tolist() == [0]
    bad = np.repeat(good, 3, axis=0)
    bad[1, 5, 3, 4] = np.nan
    bad[2, 40, 50, 60] = -0.5  # a negative mapped value unmaps to a negative stored value
    counts = invalid_counts(bad)  # the decode path's φd interpolation spreads a NaN over its (θh, θd) row
    assert counts[0] == 0 and counts[1] >= 1 and counts[2] == 1
    bad[2, 40, 50, 60] = np.inf
    assert invalid_counts(bad[2:])[0] >= 1
    below = good.copy()
    below[0, 0, 89, 89] = -1.0  # θh 89°, θd 89° at φd bin 0: below the horizon
    assert invalid_counts(below).tolist() == [0]


def test_new_holes_are_zeros_at_the_peak_that_the_source_lacked() -> None:
    source = peaked()
    edited = peaked()
    edited[GREEN_SLOT_10, 0, 10] = 0.0
    edited[GREEN_SLOT_10, 5, 10] = 0.0  # off the peak: not a hole
    assert new_holes(source, edited).sum() == 1
    assert new_holes(edited, edited).sum() == 0  # a zero the source had already
    dark = edited.copy()
    dark[GREEN_SLOT_10, 0:7, 10] = 0.0  # the whole peak region black: no hole in a highlight
    assert new_holes(source, dark).sum() == 0


def test_white_sky_albedo_of_lambertian_materials() -> None:
    albedo = np.array([0.05, 0.5, 0.95])
    stored = np.broadcast_to((albedo / np.pi / MERL_COLOR_SCALE)[:, None, None, None], (3, 90, 90, 21))
    mapped = to_network_layout(map_values(np.ascontiguousarray(stored)))
    assert white_sky_albedo(mapped) == pytest.approx(albedo, rel=1e-3)
    assert white_sky_albedo(np.zeros(NETWORK_INPUT_SHAPE)) == pytest.approx([0, 0, 0])


class PeakDecoder:
    """A constructed decoder: peak 1 − z0, flank 0.5, floor 0.3 (mapped), clamped to [0, 5] like the real one."""

    latent_dim = 2

    def __init__(self, nan_at: float | None = None) -> None:
        self.nan_at = nan_at

    def decode_mapped(self, codes: np.ndarray, *, batch_size: int = 16) -> np.ndarray:
        codes = np.asarray(codes, dtype=np.float32)
        out = np.stack([peaked(float(np.clip(1.0 - z[0], 0, 5))) for z in codes])
        if self.nan_at is not None:
            out[np.isclose(codes[:, 0], self.nan_at), 30, 20, 20] = np.nan
        return out


class Code:
    def __init__(self, name: str, mu: list[float]) -> None:
        from brdfcodec.format.bvae import LatentRecord

        self.record = LatentRecord(name, np.asarray(mu, dtype=np.float32), np.ones(len(mu), dtype=np.float32))


@pytest.mark.slow
def test_measure_plausibility_on_a_constructed_decoder() -> None:
    records = [Code("a", [0.0, 0.0]).record, Code("b", [-0.9, 0.0]).record]
    report = measure_plausibility(PeakDecoder(), records, energy_bound=False)  # the raw decodes
    # dim 0: peak 1 − z0. a (peak 1): +1σ → 0 (inverted by 0.5, a hole), +2σ, +3σ likewise; −σ brighter.
    # b (peak 1.9): +1σ → 0.9 fine, +2σ → 0 inverted, +3σ inverted.
    assert report.fractions["inverted"][0].tolist() == [0, 0, 0, 0.5, 1, 1]
    assert report.fractions["holes"][0].tolist() == [0, 0, 0, 0.5, 1, 1]
    assert report.fractions["inverted"][1].tolist() == [0] * 6  # dim 1 does nothing
    assert report.fractions["invalid"].sum() == 0
    # energy: b's μ peak (1.9) sets the limit; a at −1σ (peak 2) stays within 10 %, b at −1σ (2.9) does not
    assert report.fractions["energetic"][0].tolist() == [1, 1, 0.5, 0, 0, 0]
    assert report.fractions["unphysical"][0].tolist() == [1, 0.5, 0, 0, 0, 0]  # albedo > 1: peaks 4.9 and 3.9
    assert report.fractions["any"][0].tolist() == [1, 1, 0.5, 0.5, 1, 1]
    # a broken highlight: inverted or holes, each decode counted once
    assert report.fractions["highlight"][0].tolist() == [0, 0, 0, 0.5, 1, 1]
    worst = [o for o in report.worst if o.kind == "inverted"][0]
    assert worst.score == pytest.approx(0.5) and worst.step > 0 and worst.dim == 0
    assert report.source_inverted == 0
    json.dumps(report.to_dict(), allow_nan=False)


def test_inversions_the_source_already_has_do_not_count() -> None:
    records = [Code("dented", [0.8, 0.0]).record]  # peak 0.2 under its flank 0.5 at μ
    report = measure_plausibility(PeakDecoder(), records, dims=[0], energy_bound=False)  # the raw decodes
    assert report.source_inverted == 1
    assert report.fractions["inverted"][0].tolist() == [0, 0, 0, 0, 0, 0]
    assert report.fractions["holes"][0].tolist() == [0, 0, 0, 1, 1, 1]  # the peak still falls to 0 under its flank
    assert report.fractions["highlight"][0].tolist() == [0, 0, 0, 1, 1, 1]  # holes without inversions count


def test_an_inversion_without_a_hole_is_a_broken_highlight() -> None:
    records = [Code("c", [-0.3, 0.0]).record]  # peak 1.3 − t: 0.3 at +1σ (under its flank 0.5, above 0)
    report = measure_plausibility(PeakDecoder(), records, dims=[0], energy_bound=False)
    assert report.fractions["inverted"][0].tolist() == [0, 0, 0, 1, 1, 1]
    assert report.fractions["holes"][0].tolist() == [0, 0, 0, 0, 1, 1]
    assert report.fractions["highlight"][0].tolist() == [0, 0, 0, 1, 1, 1]


@pytest.mark.slow
def test_plausible_range_stops_before_the_first_implausible_step() -> None:
    decoder = PeakDecoder()
    # b, peak 1.9 − t: +1σ fine, +2σ inverted (0 under a flank of 0.5); −2σ (peak 3.9) has an albedo > 1
    raw = {"energy_bound": False}  # judged as the network decodes them
    assert plausible_range(decoder, Code("b", [-0.9, 0.0]).record, 0, **raw) == (-1.0, 1.0)
    # a, peak 1 − t: +1σ inverted; −3σ (peak 4) has an albedo > 1
    assert plausible_range(decoder, Code("a", [0.0, 0.0]).record, 0, **raw) == (-2.0, 0.0)
    limit = float(white_sky_albedo(peaked(2.0))[0]) * 1.1  # energy: a at −1σ (peak 2) fine, −2σ (peak 3) not
    assert plausible_range(decoder, Code("a", [0.0, 0.0]).record, 0, albedo_limit=limit, **raw) == (-1.0, 0.0)
    assert plausible_range(decoder, Code("a", [0.0, 0.0]).record, 1, **raw) == (-3.0, 3.0)
    # as edits decode (the energy bound scales a decode down to albedo 1), energy no longer ends a range
    assert plausible_range(decoder, Code("b", [-0.9, 0.0]).record, 0) == (-3.0, 1.0)
    assert plausible_range(decoder, Code("a", [0.0, 0.0]).record, 0) == (-3.0, 0.0)


class NotchDecoder(PeakDecoder):
    """Peak 1 except at z0 = 1 (and z0 = −2), where it drops to 0: implausible at one step only."""

    def decode_mapped(self, codes: np.ndarray, *, batch_size: int = 16) -> np.ndarray:
        codes = np.asarray(codes, dtype=np.float32)
        notch = np.isclose(codes[:, 0], 1.0) | np.isclose(codes[:, 0], -2.0)
        return np.stack([peaked(0.0 if n else 1.0) for n in notch])


def test_plausible_range_stops_at_the_first_implausible_step_even_if_later_ones_are_fine() -> None:
    assert plausible_range(NotchDecoder(), Code("a", [0.0, 0.0]).record, 0, energy_bound=False) == (-1.0, 0.0)


def test_measure_plausibility_counts_non_finite_decodes() -> None:
    records = [Code("a", [0.0, 0.0]).record]
    report = measure_plausibility(PeakDecoder(nan_at=-2.0), records, dims=[0])
    assert report.fractions["invalid"][0].tolist() == [0, 1, 0, 0, 0, 0]


def test_measure_plausibility_rejects_bad_arguments() -> None:
    records = [Code("a", [0.0, 0.0]).record]
    with pytest.raises(ValueError, match="dims"):
        measure_plausibility(PeakDecoder(), records, dims=[2])
    with pytest.raises(ValueError, match="no records"):
        measure_plausibility(PeakDecoder(), [])
    with pytest.raises(ValueError, match="inversion_tolerance"):
        PlausibilityCriteria(inversion_tolerance=-1)


#: The v1 model's codes (encoder means and σ) of two NBRDF-proxy materials, as its example library held them:
#: the gold-paint black hole is a regression record of that model, kept in the package so its files decode.
V1_CODES = {
    "gold-paint": ([0.5339580178260803, 1.052498459815979, 0.8193047046661377, -0.520190954208374,
                    -0.5816634893417358, -0.023433931171894073, -0.16083616018295288, -1.1392714977264404],
                   [0.00164775678422302, 0.001937229884788394, 0.00246493355371058, 0.00251145102083683,
                    0.00278239487670362, 0.0037739169783890247, 0.0035181185230612755, 0.005003512836992741]),
    "white-paint": ([0.007233893498778343, 1.7448983192443848, -0.702756941318512, -0.8171016573905945,
                     2.735748052597046, 0.07654551416635513, 2.9515914916992188, 0.24483662843704224],
                    [0.0014511741464957595, 0.0017642825841903687, 0.0022836390417069197, 0.002288002287968993,
                     0.002605573972687125, 0.003546015825122595, 0.0033274635206907988, 0.004809557925909758]),
}


@pytest.fixture(scope="module")
def default_library() -> tuple[object, dict[str, object]]:
    """The v1 model (shipped beside the default) and its records of gold-paint and white-paint."""
    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.format.bvae import LatentRecord
    from brdfcodec.models.registry import package_model_folder

    decoder = BrdfDecoder(package_model_folder("nbrdf-proxy-small-v1"))
    records = {name: LatentRecord(name, np.asarray(mu, np.float32), np.asarray(sigma, np.float32))
               for name, (mu, sigma) in V1_CODES.items()}
    return decoder, records


@pytest.mark.slow
def test_v1_model_gold_paint_black_hole_is_found(default_library: tuple[object, dict[str, object]]) -> None:
    decoder, records = default_library
    report = measure_plausibility(decoder, list(records.values()), dims=[0], energy_bound=False)  # the network's
    plus1 = report.steps.index(1.0)
    assert report.fractions["inverted"][0, plus1] >= 0.5  # gold-paint at +1σ of z1
    assert report.fractions["holes"][0, plus1] >= 0.5
    assert report.fractions["invalid"].sum() == 0
    assert any(o.material == "gold-paint" and o.kind == "holes" and o.step == 1.0 for o in report.worst)


def test_gold_paint_black_hole_is_the_linear_path_below_the_clamp(
    default_library: tuple[object, dict[str, object]],
) -> None:
    decoder, records = default_library
    mu = np.asarray(records["gold-paint"].mu)
    codes = np.stack([mu + np.eye(8)[0] * t for t in (0.0, 1.0, 2.0)])
    linear, correction = decompose_output(decoder, codes)
    raw = linear + correction
    entry = (slice(None), GREEN_SLOT_10, 0, 10)  # green, φd bin 90, θh bin 0, θd bin 10
    assert raw[entry][0] == pytest.approx(0.664, abs=0.01)
    assert raw[entry][2] < 0  # below the floor at +2σ: clamped to 0, the hole
    assert np.abs(correction[entry]).max() < 0.05  # the convolutional correction is small there
    assert np.diff(linear[entry]).max() < -0.6  # the linear path falls by > 0.6 per σ
    clamped = decoder.decode_mapped(codes)
    np.testing.assert_allclose(clamped, np.clip(raw, 0, 5), rtol=0, atol=1e-6)  # one float32 rounding apart


@pytest.mark.slow
def test_cli_plausibility_json(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["model", "plausibility", "--materials", "1", "--dims", "1", "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    summary = json.loads(captured.out)
    assert summary["dims"] == [1] and summary["materials"] == 1
    assert len(summary["fractions"]["inverted"]) == 1 and len(summary["fractions"]["inverted"][0]) == 6
    assert summary["energy_bound"] is True and summary["highlight_guard"] is False


@pytest.mark.slow
def test_cli_plausibility_judges_edits_as_they_decode_with_the_guard(capsys: pytest.CaptureFixture[str]) -> None:
    """``--highlight-guard``: the decodes `bvae edit` writes (guard, then energy bound); no pit survives it."""
    argv = ["model", "plausibility", "--materials", "2", "--dims", "4", "--json"]
    assert main(argv) == 0
    without = json.loads(capsys.readouterr().out)
    assert main([*argv, "--highlight-guard"]) == 0
    guarded = json.loads(capsys.readouterr().out)
    assert guarded["highlight_guard"] is True and guarded["energy_bound"] is True
    assert max(max(row) for row in without["fractions"]["pits"]) > 0  # z4 pits the shipped model's highlights
    assert max(max(row) for row in guarded["fractions"]["pits"]) == 0
    assert main([*argv, "--highlight-guard", "--raw"]) == 0
    assert json.loads(capsys.readouterr().out)["energy_bound"] is False


def test_cli_plausibility_bad_dims(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["model", "plausibility", "--dims", "0"]) == 2  # a usage error, like --dim 9 of 8
    assert "--dims" in capsys.readouterr().err
    assert main(["model", "plausibility", "--dims", "1,x"]) == 2
    assert main(["model", "plausibility", "--materials", "0"]) == 2
    assert main(["model", "plausibility", "--library", "/nonexistent.bvae", "--materials", "1"]) == 1
