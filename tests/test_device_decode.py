"""The device-resident decode (issue 51, item 1): ``BrdfDecoder.decode_many_tensor``.

On the CPU its tables equal ``decode_many``'s (the same float64 unmapping, in the same order) within float32
rounding, and within the cross-device tolerance of ``spec/bvae-format.md`` §9 (1e-3 mapped, every entry above the
horizon) of a float64 decode of the same network output; on CUDA (skipped without a GPU) within §9 of both.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import brdfcodec as bc
from brdfcodec.codec import BrdfDecoder, device_decode
from brdfcodec.codec.device_decode import clamp_mapped_tensor, energy_bound_scales_tensor
from brdfcodec.codec.device_lookup import merl_bins_tensor
from brdfcodec.conventions import MAPPED_MAX
from brdfcodec.edit.latent_edits import with_parameters
from brdfcodec.examples import example_library
from brdfcodec.format.bvae import GraftRecord, LatentRecord, Record
from brdfcodec.format.layered_record import LayeredRecord
from brdfcodec.layers.basis import BasisLayer, quantise_coefficients
from brdfcodec.layers.detail import encode_detail
from brdfcodec.representation import map_values
from brdfcodec.representation.energy import energy_bound_scale, energy_bound_scale_mapped
from brdfcodec.representation.layout import from_network_layout, interpolate_slices
from brdfcodec.representation.mapping import LOG_RANGE
from brdfcodec.representation.mask import horizon_mask

#: The cross-device tolerance of spec/bvae-format.md §9, in the mapped domain.
MAPPED_TOLERANCE = 1e-3
_VALID = horizon_mask()
_STORED_PER_EXPM1 = (0.01 / np.array([1.0, 1.15, 1.66]) * 1500.0)[:, None, None, None]

needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device (torch.cuda.is_available() "
                                "is false): run on a machine with a GPU")


@pytest.fixture(scope="module")
def decoder() -> BrdfDecoder:
    return BrdfDecoder()


def extreme_codes(latent_dim: int) -> np.ndarray:
    """Random codes, and codes far outside the prior (±1e3, 1e19, 1e23): the network's output saturates."""
    rng = np.random.default_rng(51)
    codes = [rng.standard_normal(latent_dim), np.full(latent_dim, 1e3), np.full(latent_dim, -1e3),
             np.full(latent_dim, 1e19), np.full(latent_dim, -1e23), rng.choice([-1e23, 1e23], latent_dim)]
    return np.stack(codes).astype(np.float32)


def plain(codes: np.ndarray) -> list[Record]:
    return [LatentRecord(f"m{i}", code, np.ones(len(code), np.float32)) for i, code in enumerate(codes)]


def mapped_of(table: np.ndarray) -> np.ndarray:
    return map_values(np.asarray(table, dtype=np.float64))


def float64_reference(mapped: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """§6 step 2 literally, in float64, from clamped network output (63, 90, 90): the mapped table (3, 90, 90, 180)."""
    reflectance_like = np.expm1(interpolate_slices(from_network_layout(mapped.astype(np.float64))) * LOG_RANGE)
    return np.log1p(scale * reflectance_like) / LOG_RANGE


def largest_mapped_difference(table: np.ndarray, reference_mapped: np.ndarray) -> float:
    valid = np.broadcast_to(_VALID, table.shape)
    return float(np.abs(mapped_of(table) - reference_mapped)[valid].max())


def assert_same_tables(got: torch.Tensor, want: list[np.ndarray]) -> None:
    """Float32 rounding apart (the device's float64 exp may differ from NumPy's in the last bit), and §9."""
    tables = got.cpu().numpy()
    assert tables.shape == (len(want), 3, 90, 90, 180)
    for table, expected in zip(tables, want, strict=True):
        np.testing.assert_allclose(table, expected, rtol=1e-6, atol=1e-9)
        assert largest_mapped_difference(table, mapped_of(expected)) <= MAPPED_TOLERANCE


@pytest.mark.slow
def test_random_and_extreme_latents_decode_as_decode_many_does(decoder: BrdfDecoder) -> None:
    records = plain(extreme_codes(decoder.latent_dim))
    got = decoder.decode_many_tensor(records, batch_size=4)
    assert isinstance(got, torch.Tensor) and got.dtype == torch.float32 and got.device == decoder.device
    assert bool(torch.isfinite(got).all())
    assert_same_tables(got, list(decoder.decode_many(records, batch_size=4)))
    assert bool((got[:, :, ~torch.from_numpy(_VALID.copy())] == -1).all())  # below the horizon: MERL's unmeasured marker


@pytest.mark.slow
def test_the_tables_are_within_the_cross_device_tolerance_of_a_float64_decode(decoder: BrdfDecoder) -> None:
    codes = extreme_codes(decoder.latent_dim)
    got = decoder.decode_many_tensor(codes, masked="keep").numpy()
    for table, mapped in zip(got, decoder.decode_mapped(codes), strict=True):
        assert largest_mapped_difference(table, float64_reference(mapped)) <= 1e-6  # the float64 order: far within §9


@pytest.mark.parametrize("masked", ["unmeasured", "zero", "keep"])
def test_every_mask_is_decode_many_s(decoder: BrdfDecoder, masked: str) -> None:
    records = plain(extreme_codes(decoder.latent_dim)[:2])
    got = decoder.decode_many_tensor(records, masked=masked)  # type: ignore[arg-type]
    want = list(decoder.decode_many(records, masked=masked))  # type: ignore[arg-type]
    for table, expected in zip(got.numpy(), want, strict=True):
        np.testing.assert_allclose(table, expected, rtol=1e-6, atol=1e-9)
        below = table[np.broadcast_to(~_VALID, table.shape)]
        assert (below == {"unmeasured": -1.0, "zero": 0.0}[masked]).all() if masked != "keep" else (below >= 0).all()


def test_codes_give_the_records_tables_and_a_tensor_input_is_taken_as_it_is(decoder: BrdfDecoder) -> None:
    codes = extreme_codes(decoder.latent_dim)[:3]
    from_records = decoder.decode_many_tensor(plain(codes))
    assert torch.equal(decoder.decode_many_tensor(torch.from_numpy(codes)), from_records)
    assert torch.equal(decoder.decode_many_tensor(codes.tolist()), from_records)  # nested lists are codes too
    assert decoder.decode_many_tensor([]).shape == (0, 3, 90, 90, 180)
    assert decoder.decode_many_tensor(np.zeros((0, decoder.latent_dim))).shape == (0, 3, 90, 90, 180)


def test_bad_input_is_refused_with_a_value_error(decoder: BrdfDecoder) -> None:
    with pytest.raises(ValueError, match="shape"):
        decoder.decode_many_tensor(np.zeros((2, decoder.latent_dim + 1)))
    with pytest.raises(ValueError, match="finite"):
        decoder.decode_many_tensor(np.full((1, decoder.latent_dim), np.nan))
    with pytest.raises(ValueError, match="masked"):
        decoder.decode_many_tensor(np.zeros((1, decoder.latent_dim)), masked="black")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="batch_size"):
        decoder.decode_many_tensor(np.zeros((1, decoder.latent_dim)), batch_size=0)
    with pytest.raises(ValueError, match="latent dimension"):
        decoder.decode_many_tensor([LatentRecord("short", np.zeros(3), np.ones(3))])
    with pytest.raises(TypeError, match="sequence of records"):
        decoder.decode_many_tensor([LatentRecord("a", np.zeros(8), np.ones(8)), np.zeros(8)])  # type: ignore[list-item]


def test_tables_are_written_into_a_given_out_tensor_that_can_be_reused(decoder: BrdfDecoder) -> None:
    codes = extreme_codes(decoder.latent_dim)[:3]
    out = torch.full((3, 3, 90, 90, 180), float("nan"))
    assert decoder.decode_many_tensor(codes, out=out) is out
    assert torch.equal(out, decoder.decode_many_tensor(codes))
    # Reused for other materials: records (an edited one takes the energy bound), every entry rewritten.
    records = plain(codes[::-1].copy())
    shifted = records[1].mu.copy()
    shifted[0] += 2.0
    records[1] = with_parameters(records[1], shifted, name="m1.z1+2", edit={"op": "traverse"})
    assert decoder.decode_many_tensor(records, masked="zero", out=out) is out
    assert torch.equal(out, decoder.decode_many_tensor(records, masked="zero"))
    empty = torch.empty((0, 3, 90, 90, 180))
    assert decoder.decode_many_tensor([], out=empty) is empty


def test_an_out_tensor_tables_cannot_go_into_is_refused_before_any_work(decoder: BrdfDecoder,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    def no_work(*args: object, **kwargs: object) -> None:
        raise AssertionError("the network ran before out was checked")

    monkeypatch.setattr(device_decode, "_network_mapped", no_work)
    monkeypatch.setattr(device_decode, "_records_mapped", no_work)
    codes = np.zeros((2, decoder.latent_dim), np.float32)
    wrong = {
        "shape": torch.zeros((3, 3, 90, 90, 180)),
        "dtype": torch.zeros((2, 3, 90, 90, 180), dtype=torch.float64),
        "contiguous": torch.zeros((2, 3, 90, 180, 90)).transpose(3, 4),
        "decoded on": torch.empty((2, 3, 90, 90, 180), device="meta"),
    }
    for message, out in wrong.items():
        before = out.clone() if out.device.type != "meta" else None
        with pytest.raises(ValueError, match=message):
            decoder.decode_many_tensor(codes, out=out)
        if before is not None:
            assert torch.equal(out, before)  # nothing written
    with pytest.raises(ValueError, match="shape"):
        decoder.decode_many_tensor(plain(codes), out=torch.zeros((1, 3, 90, 90, 180)))
    with pytest.raises(TypeError, match="torch.Tensor"):
        decoder.decode_many_tensor(codes, out=np.zeros((2, 3, 90, 90, 180), np.float32))  # type: ignore[arg-type]


def test_the_tables_go_through_dlpack_without_a_copy(decoder: BrdfDecoder) -> None:
    tables = decoder.decode_many_tensor(np.zeros((1, decoder.latent_dim), np.float32))
    shared = torch.utils.dlpack.from_dlpack(torch.utils.dlpack.to_dlpack(tables))
    assert shared.data_ptr() == tables.data_ptr() and shared.shape == tables.shape
    assert np.shares_memory(np.from_dlpack(tables), tables.numpy())  # what a CPU consumer of __dlpack__ gets


@pytest.fixture(scope="module")
def mixed(decoder: BrdfDecoder) -> list[Record]:
    """Every kind of record: an edit the bound changes, layered (basis and detail), graft, without a latent,
    projected base, plain."""
    with bc.MaterialLibrary(example_library(), decoder=decoder) as library:
        chrome = library.record("chrome")
    z = np.asarray(chrome.mu, dtype=np.float32).copy()
    z[3] -= 3.0  # chrome at z4 −3σ: far too bright for the network (tests/test_energy_bound.py)
    edited = with_parameters(chrome, z, name="chrome.z4-3", edit={"op": "traverse"})
    basis = decoder.shared_basis
    assert basis is not None
    rng = np.random.default_rng(7)
    field = np.zeros((63, 90, 90), dtype=np.float32)
    field[:21] = np.linspace(-0.3, 0.3, 90, dtype=np.float32)
    detail = encode_detail(field, 0.05)
    return [
        edited,
        LayeredRecord("both", rng.normal(size=8), np.ones(8),
                      basis=BasisLayer(basis.sha256, 0.25, rng.integers(-127, 128, size=12).astype(np.int8)),
                      detail=detail),
        LatentRecord("plain", rng.normal(size=8), np.ones(8)),
        GraftRecord("graft", rng.normal(size=8), np.ones(8), (0, 1), [2.0, -1.0]),
        LayeredRecord.without_latent("no-latent", 8, quantise_coefficients(basis.sha256, [40.0, 20.0, -3.0]),
                                     detail=detail),
        LayeredRecord("projected", rng.normal(size=8), np.ones(8),
                      basis=quantise_coefficients(basis.sha256, [3.0, -1.0, 0.5], first=8, project=50)),
    ]


@pytest.mark.slow
def test_every_record_kind_decodes_as_decode_many_does(decoder: BrdfDecoder, mixed: list[Record]) -> None:
    assert decoder.energy_scale(mixed[0]) < 0.9  # the edit's bound changes its table: otherwise nothing is tested
    got = decoder.decode_many_tensor(mixed, batch_size=2)
    assert_same_tables(got, list(decoder.decode_many(mixed, batch_size=2)))
    base = decoder.decode_many_tensor([mixed[1].base()])[0].numpy()  # type: ignore[attr-defined]
    assert largest_mapped_difference(got[1].numpy(), mapped_of(base)) > 0.1  # the layers were added


def test_mixed_records_at_any_batch_size_see_decode_many_s_network_batches(decoder: BrdfDecoder,
                                                                         mixed: list[Record]) -> None:
    """A graft before plain records, at the default batch size and at an odd one: the network takes the plain
    codes in the batches decode_many gives it (its output differs in the last bits from batch to batch), so the
    tables and the values at directions are decode_many's."""
    from brdfcodec.codec.device_decode import network_batches

    rng = np.random.default_rng(21)
    plains = [LatentRecord(f"p{i}", rng.normal(size=8), np.ones(8)) for i in range(4)]
    records = [mixed[3], *plains]  # the graft first: the pairs are of the plain records, not of positions
    assert [(b.start, b.stop) for b in network_batches(decoder, 7, 3)] == [(0, 2), (2, 3), (3, 5), (5, 6), (6, 7)]
    wi, wo = np.array([[0.3, 0.1, 0.9]]), np.array([[-0.2, 0.4, 0.8]])
    for batch_size in (16, 3):
        want = list(decoder.decode_many(records, batch_size=batch_size))
        got = decoder.decode_many_tensor(records, batch_size=batch_size).numpy()
        for table, expected in zip(got, want, strict=True):
            np.testing.assert_allclose(table, expected, rtol=1e-6, atol=1e-9)
        values = decoder.evaluate_tensor(records, wi, wo, batch_size=batch_size)[:, 0].numpy()
        h, d, p, _ = (int(t.reshape(-1)[0]) for t in merl_bins_tensor(torch.from_numpy(wi), torch.from_numpy(wo)))
        for value, table in zip(values, want, strict=True):  # decode_many's table at the direction's bin
            np.testing.assert_allclose(value, table[:, h, d, p], rtol=5e-7)


def test_a_bad_record_is_refused_before_any_row_is_written(decoder: BrdfDecoder) -> None:
    from brdfcodec.errors import LatentDimensionError

    rng = np.random.default_rng(22)
    records = [LatentRecord(f"p{i}", rng.normal(size=8), np.ones(8)) for i in range(4)]
    records.append(LatentRecord("wide", rng.normal(size=9), np.ones(9)))
    out = torch.full((5, 3, 90, 90, 180), 7.0)
    with pytest.raises((LatentDimensionError, ValueError)):
        decoder.decode_many_tensor(records, out=out)
    assert bool((out == 7.0).all())  # nothing written
    with pytest.raises((LatentDimensionError, ValueError)):
        decoder.evaluate_tensor(records, np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, 1.0]]))


def test_the_energy_bound_can_be_forced_on_or_off(decoder: BrdfDecoder, mixed: list[Record]) -> None:
    edited, other = mixed[0], mixed[2]
    off = decoder.decode_many_tensor([edited], energy_bound=False)[0].numpy()
    np.testing.assert_allclose(off, decoder.decode(edited, energy_bound=False), rtol=1e-6, atol=1e-9)
    on = decoder.decode_many_tensor([other], energy_bound=True)[0].numpy()
    np.testing.assert_allclose(on, decoder.decode(other, energy_bound=True), rtol=1e-6, atol=1e-9)
    codes = np.asarray(edited.mu, dtype=np.float32)[None]
    unedited = LatentRecord(edited.name, edited.mu, edited.sigma)  # no highlight guard: only the bound asked for
    np.testing.assert_array_equal(decoder.decode_many_tensor(codes, energy_bound=True)[0].numpy(),
                                  decoder.decode_many_tensor([unedited], energy_bound=True)[0].numpy())


def test_the_bound_s_factor_is_the_numpy_quadrature_s(decoder: BrdfDecoder, mixed: list[Record]) -> None:
    mapped = np.stack([decoder.mapped_record(r, energy_bound=False) for r in mixed[:3]])
    got = energy_bound_scales_tensor(torch.from_numpy(mapped)).numpy()
    want = [energy_bound_scale_mapped(m) for m in mapped]
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert got[0] < 0.9 and (got <= 1.0).all()
    table = decoder.decode_many_tensor([mixed[0]], masked="keep", energy_bound=False)[0].numpy()
    assert got[0] == pytest.approx(energy_bound_scale(table), rel=1e-5)  # the albedo of the interpolated table


def test_the_clamp_is_clamp_mapped_s() -> None:
    values = torch.tensor([-1.0, float("nan"), 2.0, 9.0, float("inf"), -float("inf")])
    assert clamp_mapped_tensor(values).tolist() == [0.0, 0.0, 2.0, MAPPED_MAX, MAPPED_MAX, 0.0]


@needs_cuda
def test_on_cuda_the_tables_stay_on_the_device_and_meet_the_cross_device_tolerance(mixed: list[Record]) -> None:
    """Run on a GPU: §9's 1e-3 mapped against a float64 decode of the CUDA network's own output, and against the
    CPU's NumPy decode_many (which also covers the network's CPU/CUDA difference)."""
    cpu, cuda = BrdfDecoder(), BrdfDecoder(device="cuda")
    codes = np.concatenate([extreme_codes(cuda.latent_dim),
                            np.random.default_rng(0).standard_normal((58, cuda.latent_dim)).astype(np.float32)])
    got = cuda.decode_many_tensor(torch.from_numpy(codes).cuda(), masked="keep")
    assert got.device.type == "cuda" and got.dtype == torch.float32
    assert got.device == cuda.device  # the decoder's device is indexed (cuda:N), as its tensors
    tables = got.cpu().numpy()
    for table, mapped in zip(tables, cuda.decode_mapped(codes), strict=True):
        assert largest_mapped_difference(table, float64_reference(mapped)) <= MAPPED_TOLERANCE
    for table, expected in zip(tables, cpu.decode_many(plain(codes), masked="keep"), strict=True):
        assert largest_mapped_difference(table, mapped_of(expected)) <= MAPPED_TOLERANCE
    records = cuda.decode_many_tensor(mixed).cpu().numpy()
    for table, expected in zip(records, cpu.decode_many(mixed), strict=True):
        assert largest_mapped_difference(table, mapped_of(expected)) <= MAPPED_TOLERANCE
    out = torch.full((len(codes), 3, 90, 90, 180), float("nan"), device="cuda")  # a renderer's reused buffer
    assert cuda.decode_many_tensor(torch.from_numpy(codes).cuda(), masked="keep", out=out) is out
    for again, first in zip(out.cpu().numpy(), tables, strict=True):  # a GPU may pick other kernels (TF32 convs)
        assert largest_mapped_difference(again, mapped_of(first)) <= MAPPED_TOLERANCE
    with pytest.raises(ValueError, match="decoded on"):
        cuda.decode_many_tensor(codes, out=torch.empty((len(codes), 3, 90, 90, 180)))  # a host tensor


@pytest.mark.parametrize("masked", ["unmeasured", "zero", "keep"])
def test_the_gpu_s_float32_unmapping_is_within_1e_6_mapped_of_a_float64_decode(decoder: BrdfDecoder,
                                                                              masked: str) -> None:
    """The tensor steps a GPU takes (``unmap_kept_slices``: float32 interpolation and ``expm1`` over the full
    table), run here on the CPU: dark, bright, saturated and black slices, an energy-bound factor; every entry
    above the horizon within 1e-6 mapped of a float64 decode, and the host decode's table to float32 rounding of
    arguments up to L · 5 (relative 5e-6)."""
    codes = np.random.default_rng(5).standard_normal((4, decoder.latent_dim)).astype(np.float32)
    mapped = torch.from_numpy(np.stack(decoder.decode_mapped(codes)).copy())
    mapped[0, :, :20] *= 1e-4  # dark rows, where the exponential amplifies rounding
    mapped[1, :, 40:] = MAPPED_MAX  # the clamp's top, x = L · 5
    mapped[2] = 0.0  # black
    scales = torch.tensor([1.0, 0.25, 1.0, 0.5], dtype=torch.float64)
    fill = device_decode._mask_fill(masked)
    out = torch.full((4, 3, 90, 90, 180), float("nan"))
    got = device_decode._tables_by_tensor_steps(mapped, scales, fill, out)
    assert got is out and bool(torch.isfinite(got).all())
    host = device_decode.tables_from_mapped_tensor(mapped, scales, masked=masked)  # type: ignore[arg-type]
    np.testing.assert_allclose(got.numpy(), host.numpy(), rtol=5e-6, atol=1e-12)
    for table, slices, scale in zip(got.numpy(), mapped.numpy(), scales.tolist(), strict=True):
        assert largest_mapped_difference(table, float64_reference(slices, scale)) <= 1e-6
        below = table[np.broadcast_to(~_VALID, table.shape)]
        assert (below == fill).all() if fill is not None else (below >= 0).all()
    assert bool((got[2] == torch.where(torch.from_numpy(_VALID.copy()), 0.0, fill or 0.0)).all())  # black is 0


def test_codes_beyond_the_latent_limit_decode_as_the_limit(decoder: BrdfDecoder) -> None:
    """spec §6 step 2: each coordinate is clipped to ±LATENT_LIMIT at the decoder's input, in every entry point of
    the network (so that 1e19 decodes alike on every device); within the bound the codes are untouched."""
    from brdfcodec.conventions import LATENT_LIMIT
    from brdfcodec.models.network import clip_latent

    codes = extreme_codes(decoder.latent_dim)[3:]  # 1e19, -1e23, ±1e23
    clipped = np.clip(codes, -LATENT_LIMIT, LATENT_LIMIT)
    assert not np.array_equal(codes, clipped)
    np.testing.assert_array_equal(decoder.decode_mapped(codes), decoder.decode_mapped(clipped))
    network = decoder.network.eval()
    with torch.no_grad():
        far, bound = torch.from_numpy(codes), torch.from_numpy(clipped)
        assert torch.equal(network.forward_channels(far, (0, 21)), network.forward_channels(bound, (0, 21)))
        assert torch.equal(network.hidden_and_unbounded(far)[1], network.hidden_and_unbounded(bound)[1])
        assert torch.equal(network.logits(far), network.logits(bound))
    basis = decoder.shared_basis
    assert basis is not None
    layer = quantise_coefficients(basis.sha256, [3.0, -1.0, 0.5], first=8, project=50)  # a projected base (§4.5)
    projected_far = LayeredRecord("far", codes[0], np.ones(len(codes[0])), basis=layer)
    projected_bound = LayeredRecord("bound", clipped[0], np.ones(len(codes[0])), basis=layer)
    np.testing.assert_array_equal(decoder.decode(projected_far, masked="keep"),
                                  decoder.decode(projected_bound, masked="keep"))  # its fast path clips too
    inside = torch.tensor([[-LATENT_LIMIT, -3.0, 0.0, 2.5, LATENT_LIMIT]], requires_grad=True)
    clip_latent(inside).sum().backward()
    assert torch.equal(clip_latent(inside.detach()), inside.detach())
    assert torch.equal(inside.grad, torch.ones_like(inside))  # training and edits see the identity
