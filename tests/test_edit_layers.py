"""Edits keep the layers (issue 41, part 6; ``spec/bvae-format.md`` §4.4, "Edits").

An edit of a layered record moves its base code and keeps its basis and
detail layers, so the edited material is clamp(B(μ′) + L): the edited base
plus the original layers' residual L in the mapped domain. Moving μ′ back
returns the original decode, guarded as every edit's is (§6 step 6). Material: an analytic red plastic compressed
into 16 KB with the shipped model (a basis layer and a detail layer).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from brdfcodec.codec import BrdfDecoder
from brdfcodec.edit.latent_edits import graft, interpolate, mix_factors, traverse, with_parameters
from brdfcodec.format.bvae import GraftRecord, LatentRecord, read_bvae, write_bvae
from brdfcodec.format.layered_record import LayeredRecord
from brdfcodec.layers.layer_sum import layered_residual
from brdfcodec.representation import clamp_mapped
from brdfcodec.representation.highlight_guard import guard_highlight

pytestmark = pytest.mark.slow  # the 16 KB record takes rate control (about 15 s on 2 busy cores)

#: Largest mapped difference between an undone edit's decode and the original decode: μ′ − δ + δ is μ
#: within a float32 rounding (about 1e-7), which moves the decode by far less than this.
UNDO_TOLERANCE = 1e-5


@pytest.fixture(scope="module")
def layered(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    from brdfcodec.codec import compress
    from brdfcodec.datasets.analytic import ANALYTIC_PRESETS

    folder = tmp_path_factory.mktemp("edit-layers")
    path = folder / "rp16k.bvae"
    compress([ANALYTIC_PRESETS["red-plastic"].to_merl()], path, names=["rp"], bytes=16384, measure_error=False)
    library = read_bvae(path)
    decoder = BrdfDecoder.for_header(library.header)
    record = library.records[0]
    decode = decoder.mapped_record(record)
    # An edit decodes with the highlight guard (spec/bvae-format.md §6 step 6): an edit that returns to the
    # record's code decodes as its guarded slices.
    return {"path": path, "folder": folder, "record": record, "decoder": decoder,
            "decode": decode, "guarded": guard_highlight(decode)}


def layers_sum(decoder: BrdfDecoder, record: LayeredRecord) -> np.ndarray:
    residual = layered_residual(decoder.shared_basis, record.basis, record.detail)
    assert residual is not None
    return residual


def base_decode(decoder: BrdfDecoder, record: LayeredRecord, mu: np.ndarray) -> np.ndarray:
    """B(μ): the clamped base decode, projected where the record's basis layer says so."""
    mapped = decoder.decode_mapped(mu)
    decoder.project_base(record, mapped)
    return mapped


def test_the_record_is_a_16_kb_layered_record_with_both_layers(layered: dict[str, Any]) -> None:
    record = layered["record"]
    assert isinstance(record, LayeredRecord)
    assert record.basis is not None and record.detail is not None
    assert 8192 < layered["path"].stat().st_size <= 16384


@pytest.mark.parametrize(("dim", "step"), [(0, 1.5), (3, -1.5), (6, 3.0)])
def test_an_edit_is_the_edited_base_plus_the_original_layers(layered: dict[str, Any], dim: int, step: float) -> None:
    record, decoder = layered["record"], layered["decoder"]
    edited = traverse(record, dim, [step])[0]
    assert isinstance(edited, LayeredRecord)
    assert edited.basis == record.basis and edited.detail == record.detail
    assert edited.mu[dim] == pytest.approx(record.mu[dim] + step)
    # The layers' rule (§4.4); the highlight guard (§6 step 6) and the bound (step 5) come after it.
    got = decoder._unguarded_mapped(edited)
    np.testing.assert_array_equal(decoder.mapped_record(edited, energy_bound=False), guard_highlight(got))
    residual = layers_sum(decoder, record)
    want = clamp_mapped(base_decode(decoder, record, edited.mu) + residual)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
    # Where no clamp acts, it is the edited base plus (original decode − original base).
    original_base = base_decode(decoder, record, record.mu)
    unclamped = base_decode(decoder, record, edited.mu) + (layered["decode"] - original_base)
    free = (np.abs(clamp_mapped(unclamped.copy()) - unclamped) == 0) & (
        np.abs(clamp_mapped(original_base + residual) - (original_base + residual)) == 0)
    assert free.mean() > 0.5
    np.testing.assert_allclose(got[free], unclamped[free], rtol=0, atol=1e-5)
    # ... and far from "edited base only", which is what dropping the layers gave.
    base_only = decoder.mapped_record(LatentRecord("b", edited.mu, edited.sigma))
    assert np.abs(got - base_only).mean() > 10 * np.abs(got - want).mean() + 1e-3


@pytest.mark.parametrize(("dim", "step"), [(1, 1.5), (4, -0.37), (7, 3.0)])
def test_traversing_back_returns_the_original_decode(layered: dict[str, Any], dim: int, step: float) -> None:
    record, decoder = layered["record"], layered["decoder"]
    edited = traverse(record, dim, [step])[0]
    assert np.abs(decoder.mapped_record(edited) - layered["decode"]).max() > 1e-3  # the edit did something
    back = traverse(edited, dim, [-step])[0]
    assert isinstance(back, LayeredRecord)
    assert np.abs(decoder.mapped_record(back, energy_bound=False) - layered["guarded"]).max() < UNDO_TOLERANCE


def test_interpolating_back_returns_the_original_and_keeps_the_first_operands_layers(
    layered: dict[str, Any],
) -> None:
    record, decoder = layered["record"], layered["decoder"]
    other = LatentRecord("other", np.linspace(-1, 1, 8).astype(np.float32), np.ones(8, np.float32))
    half = interpolate(record, other, 0.5)
    assert isinstance(half, LayeredRecord) and half.detail == record.detail
    back = interpolate(half, record, 1.0)
    np.testing.assert_array_equal(back.mu, record.mu)
    np.testing.assert_array_equal(decoder.mapped_record(back, energy_bound=False), layered["guarded"])
    mixed = mix_factors(record, other, [0, 1])
    assert isinstance(mixed, LayeredRecord) and mixed.basis == record.basis
    np.testing.assert_array_equal(mixed.mu[2:], other.mu[2:])
    # A plain first operand: a plain result (the second operand's layers are not used).
    assert not isinstance(interpolate(other, record, 0.5), LayeredRecord)


def test_a_graft_of_a_layered_record_is_of_its_base(layered: dict[str, Any]) -> None:
    record, decoder = layered["record"], layered["decoder"]
    grafted = graft(record, [0.5, -1.0], decoder.colour_dims)
    assert isinstance(grafted, GraftRecord)
    np.testing.assert_array_equal(grafted.mu, record.mu)


def test_a_compact_mu_is_kept_only_where_it_holds_the_edited_code() -> None:
    from brdfcodec.layers.detail import encode_detail

    residual = np.zeros((63, 90, 90), np.float32)
    residual[0, 10, 10] = 0.5
    detail = encode_detail(residual, 0.01)
    mu = np.arange(-4, 4, dtype=np.float32) / 4
    record = LayeredRecord("c", mu, np.ones(8, np.float32), detail=detail, compact_mu=True, fixed_mu_grid=True)
    on_grid = traverse(record, 2, [0.5])[0]  # 16/32: on the fixed grid
    assert on_grid.compact_mu and on_grid.fixed_mu_grid and on_grid.mu[2] == record.mu[2] + 0.5
    off_grid = traverse(record, 2, [0.1])[0]
    assert not off_grid.compact_mu and off_grid.mu[2] == np.float32(record.mu[2] + np.float32(0.1))
    same = with_parameters(record, record.mu, name="c", edit={"op": "traverse"})
    assert same.compact_mu and same.layer_bytes() == record.layer_bytes()


def test_bvae_edit_traverse_and_back_on_a_16_kb_record(layered: dict[str, Any]) -> None:
    from brdfcodec.cli.main import main

    folder, decoder = layered["folder"], layered["decoder"]
    up, down = folder / "up.bvae", folder / "down.bvae"
    assert main(["edit", "traverse", str(layered["path"]), "--dim", "3", "--values", "1.5", "-o", str(up),
                 "--force"]) == 0
    edited = read_bvae(up).records[0]
    assert isinstance(edited, LayeredRecord) and edited.detail == layered["record"].detail
    assert main(["edit", "traverse", str(up), "--dim", "3", "--values=-1.5", "-o", str(down), "--force"]) == 0
    back = read_bvae(down).records[0]
    assert np.abs(decoder.mapped_record(back, energy_bound=False) - layered["guarded"]).max() < UNDO_TOLERANCE
    both = folder / "both.bvae"
    write_bvae(both, [layered["record"], LatentRecord("plain", np.zeros(8, np.float32), np.ones(8, np.float32))],
               decoder.reference, overwrite=True)
    mixed = folder / "mixed.bvae"
    assert main(["edit", "interp", str(both), "rp", "plain", "--t", "0.25", "-o", str(mixed), "--force"]) == 0
    assert isinstance(read_bvae(mixed).records[0], LayeredRecord)


def test_bvae_edit_graft_on_a_layered_record_says_the_layers_are_left_out(
    layered: dict[str, Any], capsys: pytest.CaptureFixture[str]
) -> None:
    from brdfcodec.cli.main import main

    out = layered["folder"] / "graft.bvae"
    assert main(["edit", "graft", str(layered["path"]), "--values", "0.5,-1", "-o", str(out), "--force"]) == 0
    assert "no layers" in capsys.readouterr().out
    assert isinstance(read_bvae(out).records[0], GraftRecord)


def test_the_studio_edits_a_layered_record_with_its_layers(layered: dict[str, Any], tmp_path: Path) -> None:
    from brdfcodec.studio.catalogue import Catalogue
    from brdfcodec.studio.server import StudioServer

    catalogue = Catalogue([layered["path"]])
    record, decoder = layered["record"], layered["decoder"]
    z = [float(v) for v in record.mu]
    edited_record = catalogue.edited_record({"base": "rp", "z": z, "graft": None})
    # The base's own code is not an edit (catalogue.edited_record): the material as encoded, no guard.
    np.testing.assert_array_equal(decoder.mapped_record(edited_record), layered["decode"])
    z[2] += 1.0
    moved = catalogue.edited_record({"base": "rp", "z": z, "graft": None})
    assert isinstance(moved, LayeredRecord)
    np.testing.assert_array_equal(decoder.mapped_record(moved), decoder.mapped_record(traverse(record, 2, [1.0])[0]))
    server = StudioServer(catalogue, save_dir=tmp_path)
    server.save({"file": "saved.bvae", "name": "saved", "base": "rp", "z": z, "graft": None,
                 "edit": {"source": "rp", "changed": [2]}})
    saved = read_bvae(tmp_path / "saved.bvae").records[0]
    assert isinstance(saved, LayeredRecord) and saved.detail == record.detail and saved.meta["edit"]["op"] == "studio"


def test_a_projected_compact_record_edits_by_the_same_rule(layered: dict[str, Any]) -> None:
    """A 64 B record: μ on the fixed int8 grid, a basis layer only, the base projected on the shared basis."""
    from brdfcodec.cli.main import main
    from brdfcodec.datasets.analytic import ANALYTIC_PRESETS
    from brdfcodec.io.merl import write_merl

    folder, decoder = layered["folder"], layered["decoder"]
    source, path = folder / "rp.binary", folder / "rp64.bvae"
    write_merl(source, ANALYTIC_PRESETS["red-plastic"].to_merl(), overwrite=True)
    assert main(["compress", str(source), "--bytes", "64", "--project-base", "always", "--latent", "always",
                 "--basis-coding", "packed", "--no-measure", "-o", str(path), "--force"]) == 0  # μ on the grid
    record = read_bvae(path).records[0]
    assert isinstance(record, LayeredRecord) and record.basis is not None and record.basis.project > 0
    assert record.compact_mu and record.fixed_mu_grid and record.detail is None
    original = decoder.mapped_record(record)
    for dim, step, stays_compact in ((0, 1.5, True), (3, -0.37, False)):
        edited = traverse(record, dim, [step])[0]
        assert isinstance(edited, LayeredRecord) and edited.basis == record.basis
        assert edited.compact_mu is stays_compact
        want = guard_highlight(clamp_mapped(base_decode(decoder, record, edited.mu) + layers_sum(decoder, record)))
        np.testing.assert_allclose(decoder.mapped_record(edited, energy_bound=False), want, rtol=0, atol=1e-5)
        back = traverse(edited, dim, [-step])[0]
        assert np.abs(decoder.mapped_record(back, energy_bound=False) - guard_highlight(original)).max() < UNDO_TOLERANCE
