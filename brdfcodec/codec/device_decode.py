"""Full tables decoded as torch tensors on the decoder's device (issue 51, item 1).

Part of :mod:`brdfcodec.codec`; reached through :meth:`BrdfDecoder.decode_many_tensor
<brdfcodec.codec.BrdfDecoder.decode_many_tensor>`.

The steps of ``spec/bvae-format.md`` §6 after the network — clamp, layers, interpolation of the 21 kept φd
slices to 180 bins, unmapping to stored MERL units, the energy bound of edited records, the horizon mask —
run as tensor operations where the network ran, and the tables stay there: a renderer on a GPU takes them
without a copy through the host (DLPack: ``torch.utils.dlpack.to_dlpack(tables)`` or the tensor's
``__dlpack__``, which ``drjit``, ``jax.dlpack.from_dlpack`` and ``cupy.from_dlpack`` accept).

On a GPU the unmapping (:func:`unmap_kept_slices`) takes ``x = L · m`` and the step through each gap between
kept slices in float64 at the kept slices, then interpolates ``x`` and takes one ``expm1`` per bin in float32
over the full table: four passes over the table's memory, and no float64 array of the table's size. It is
within 1e-6 mapped of a float64 decode (``spec/bvae-format.md`` §9, whose cross-device
tolerance is 1e-3 mapped). The energy bound's albedo is the NumPy path's quadrature
(``representation/energy.py``), summed on the device in another order (a relative difference of about 1e-15 in
the factor). On the CPU the tables are the host decode's (:func:`table_from_mapped_host`, what
``BrdfDecoder.decode`` and ``decode_many`` use: float64 interpolation and unmapping, one exponential per kept
slice and one per gap, written into the tensor), so the two CPU paths give the same tables.

What stays on the host: records that are not a plain latent decode — grafts (two codes), records whose base is
projected on the shared basis (format 1.6), records without a latent (format 2.1) — get their mapped slices
from the NumPy path (:meth:`BrdfDecoder._mapped_record`), moved to the device (2 MB each) for the table; a
layered record's layers (basis sum, inverse DCT of the detail layer) are decoded on the host and added to the
network output on the device, before the one clamp (§4.4).
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Sequence
from typing import TYPE_CHECKING, Protocol

import numpy as np
import numpy.typing as npt
import torch

from brdfcodec.codec.devices import indexed_device
from brdfcodec.conventions import (
    EPSILON,
    KEPT_PHI_D_SLICES,
    MAPPED_MAX,
    MERL_COLOR_SCALE,
    N_CHANNELS,
    N_KEPT_SLICES,
    N_PHI_D,
    N_THETA_D,
    N_THETA_H,
    UNMEASURED_VALUE,
)
from brdfcodec.format.bvae import LatentRecord, Record
from brdfcodec.representation.energy import _quadrature
from brdfcodec.representation.highlight_guard import guard_highlight
from brdfcodec.representation.layout import interpolation_plan
from brdfcodec.representation.mapping import LOG_RANGE
from brdfcodec.representation.mask import horizon_mask
from brdfcodec.representation.network_io import _GAP_LENGTHS, over_theta_h_rows, stepped_table
from brdfcodec.representation.stepped_kernel import compiled_log_arguments
from brdfcodec.runtime.threads import codec_threads

if TYPE_CHECKING:
    from brdfcodec.codec.prepare import MaskedEntries


class BrdfDecoder(Protocol):
    """What this module reads of :class:`brdfcodec.codec.BrdfDecoder` (named here, not imported: the decoder
    imports this module)."""

    device: torch.device
    dtype: torch.dtype
    network: torch.nn.Module
    latent_dim: int

    def _layer_residuals(self, record: Record) -> list[np.ndarray]: ...

    def _mapped_record(self, record: Record) -> np.ndarray: ...

    def _check_record(self, record: Record) -> None: ...

__all__ = [
    "check_tables_out", "clamp_mapped_tensor", "decode_many_tensor", "energy_bound_scales_tensor",
    "records_or_codes", "table_from_mapped_host", "tables_from_mapped_tensor", "unmap_kept_slices",
]

#: Bins from one kept slice to the next (the last gap, 171 → 179, holds 8).
_GAP = KEPT_PHI_D_SLICES[1] - KEPT_PHI_D_SLICES[0]
#: ε / S_c per channel: stored units per unit of ``expm1`` (as in ``representation/network_io.py``).
_STORED_PER_EXPM1 = EPSILON / np.asarray(MERL_COLOR_SCALE, dtype=np.float64)
#: Records whose energy bound is computed at once on the CPU (the float64 working arrays stay in cache).
_CPU_CHUNK = 1
#: Records unmapped at once on other devices (working arrays of about 8 MB a record beside the table), and
#: whose energy bound is computed at once.
_DEVICE_CHUNK = 64


def clamp_mapped_tensor(mapped: torch.Tensor) -> torch.Tensor:
    """Clamp mapped values to ``[0, MAPPED_MAX]`` in place, NaN to 0, ±inf to the bounds (as ``clamp_mapped``).

    Parameters
    ----------
    mapped : torch.Tensor of float32, any shape
        Mapped values (network output, or base plus layers).

    Returns
    -------
    torch.Tensor
        ``mapped`` itself, every entry finite in ``[0, MAPPED_MAX]``.
    """
    torch.nan_to_num_(mapped, nan=0.0, posinf=MAPPED_MAX, neginf=0.0)
    return mapped.clamp_(0.0, MAPPED_MAX)


@functools.cache
def _constants(device: torch.device) -> dict[str, torch.Tensor]:
    """Per-device constants: the below-horizon bins, the gap lengths, ε / S_c (built once per device)."""
    return {
        "invalid": torch.from_numpy(~horizon_mask()).to(device),  # (90, 90, 180) bool
        "steps": torch.from_numpy(_GAP_LENGTHS.copy()).to(device),  # (20,)
        "stored": torch.from_numpy(_STORED_PER_EXPM1.copy()).to(device),  # (3,) float64
    }


@functools.cache
def _quadrature_on(device: torch.device) -> dict[str, torch.Tensor]:
    """The energy bound's quadrature on a device: flat kept-slice indices of each node's two neighbours, the
    right one's interpolation weight, the node's weight and its incident-elevation row (float64 / int64)."""
    h, d, p, weight, row = _quadrature()
    left, right, t = interpolation_plan()
    plane = N_THETA_H * N_THETA_D
    return {
        "left": torch.from_numpy((left[p] * plane + h * N_THETA_D + d).astype(np.int64)).to(device),
        "right": torch.from_numpy((right[p] * plane + h * N_THETA_D + d).astype(np.int64)).to(device),
        "t": torch.from_numpy(np.array(t[p], dtype=np.float64)).to(device),
        "weight": torch.from_numpy(np.array(weight, dtype=np.float64)).to(device),
        "row": torch.from_numpy(np.array(row, dtype=np.int64)).to(device),
        "rows": torch.tensor(int(row.max()) + 1),
    }


def energy_bound_scales_tensor(mapped: torch.Tensor) -> torch.Tensor:
    """The energy bound's factors ``min(1, 1 / max a)`` of clamped mapped slices, on their device.

    The same quadrature as :func:`~brdfcodec.representation.energy.energy_bound_scale_mapped`: each node
    reads its φd bin as the interpolation makes it, unmapped to reflectance, in float64.

    Parameters
    ----------
    mapped : torch.Tensor of float32, shape (B, 63, 90, 90)
        Clamped mapped slices (network layout).

    Returns
    -------
    torch.Tensor of float64, shape (B,)
        Factors on reflectance, in (0, 1], on ``mapped``'s device.
    """
    q = _quadrature_on(mapped.device)
    flat = mapped.reshape(mapped.shape[0], N_CHANNELS, -1)  # (B, 3, 21·90·90), kept slot major
    low = flat[:, :, q["left"]].double()
    high = flat[:, :, q["right"]].double()
    value = (1.0 - q["t"]) * low + q["t"] * high
    albedo = torch.expm1(value.mul_(LOG_RANGE)).mul_(EPSILON).mul_(q["weight"])  # (B, 3, n)
    sums = value.new_zeros((mapped.shape[0], N_CHANNELS, int(q["rows"]))).index_add_(2, q["row"], albedo)
    largest = sums.amax(dim=(1, 2))
    return torch.where(largest > 1.0, 1.0 / largest.clamp(min=1.0), torch.ones_like(largest))


def unmap_kept_slices(kept: torch.Tensor, factor: torch.Tensor, target: torch.Tensor) -> None:
    """``factor_c · expm1(L · m)`` at all 180 φd bins of kept mapped slices, written into ``target``.

    The device decode's unmapping (``spec/bvae-format.md`` §6 step 2), in four passes over the full table:
    ``x = L · m`` and the steps ``(x_b − x_a) / n`` of the 20 gaps in float64 at the kept slices (a ninth of the
    table), rounded to float32; then, in float32 on the full table, ``x_a + j · step`` for the offsets j = 0…8 of
    each gap (bin 179 is the last kept slice's own ``x``), ``expm1`` and the factor. Against a float64 decode
    this is within 1e-6 in the mapped domain (the float32 rounding of ``x`` ≤ L · 5 = 23 moves the mapped value by
    a few 1e-7), far within §9's cross-device 1e-3; ``tests/test_device_decode.py`` measures it on dark, bright
    and saturated tables.

    Parameters
    ----------
    kept : torch.Tensor of float32, shape (C, 3, R, 90, 21)
        Clamped mapped values at the kept φd slices, kept slice last (values in ``[0, MAPPED_MAX]``).
    factor : torch.Tensor of float64, shape (C, 3)
        Stored MERL units per unit of ``expm1`` per table and channel (ε / S_c times the energy bound's factor).
    target : torch.Tensor of float32, shape (C, 3, R, 90, 180)
        Contiguous; overwritten with the tables in stored MERL units (no mask).
    """
    x = kept.to(dtype=torch.float64, memory_format=torch.contiguous_format).mul_(LOG_RANGE)
    start = x[..., :-1].float().unsqueeze(-1)
    step = (x[..., 1:] - x[..., :-1]).div_(_constants(kept.device)["steps"]).float().unsqueeze(-1)
    offsets = torch.arange(_GAP, dtype=torch.float32, device=kept.device)
    gaps = target.view(*target.shape[:-1], N_KEPT_SLICES - 1, _GAP)  # bin g · 9 + j of gap g
    torch.addcmul(start, step, offsets, out=gaps)
    target[..., N_PHI_D - 1] = x[..., -1]  # bin 179: the last kept slice itself (not a + 8 · step, rounded)
    target.expm1_().mul_(factor.float().reshape(*factor.shape, 1, 1, 1))


def check_tables_out(out: torch.Tensor, count: int, device: torch.device) -> None:
    """Refuse an ``out`` tensor that full tables cannot be written into.

    Parameters
    ----------
    out : torch.Tensor
        Must be float32, contiguous, of shape (count, 3, 90, 90, 180), on ``device``.
    count : int
        Tables to write.
    device : torch.device
        Where they are decoded.

    Raises
    ------
    TypeError
        ``out`` is not a torch tensor.
    ValueError
        Its shape, dtype, device or layout is not the one above (the message says which).
    """
    if not isinstance(out, torch.Tensor):
        raise TypeError(f"out must be a torch.Tensor, got {type(out).__name__}")
    shape = (count, N_CHANNELS, N_THETA_H, N_THETA_D, N_PHI_D)
    if tuple(out.shape) != shape:
        raise ValueError(f"out has shape {tuple(out.shape)}; {count} tables need {shape}")
    if out.dtype != torch.float32:
        raise ValueError(f"out has dtype {out.dtype}; tables are torch.float32")
    if out.device != indexed_device(device):
        raise ValueError(f"out is on {out.device}; the tables are decoded on {device}")
    if not out.is_contiguous():
        raise ValueError("out must be contiguous")


def tables_from_mapped_tensor(
    mapped: torch.Tensor,
    scales: torch.Tensor | None = None,
    *,
    masked: MaskedEntries = "unmeasured",
    out: torch.Tensor | None = None,
) -> torch.Tensor:
    """Full tables in stored MERL units from clamped mapped slices, on their device.

    Parameters
    ----------
    mapped : torch.Tensor of float32, shape (B, 63, 90, 90)
        Clamped mapped slices (network layout), values in ``[0, MAPPED_MAX]``.
    scales : torch.Tensor of float64, shape (B,), optional
        Factor ≥ 0 on reflectance per table (the energy bound, ``spec/bvae-format.md`` §6 step 5), applied to
        the interpolated table; 1 by default.
    masked : {"unmeasured", "zero", "keep"}, default "unmeasured"
        Below-horizon bins: −1, 0, or the decoded value.
    out : torch.Tensor of float32, shape (B, 3, 90, 90, 180), optional
        Where to write the tables (contiguous, on ``mapped``'s device; checked by :func:`check_tables_out`);
        a new tensor by default.

    Returns
    -------
    torch.Tensor of float32, shape (B, 3, 90, 90, 180)
        ``out`` when given; on ``mapped``'s device; finite, ≥ 0 above the horizon.
    """
    fill = _mask_fill(masked)
    count = mapped.shape[0]
    if out is None:
        out = torch.empty((count, N_CHANNELS, N_THETA_H, N_THETA_D, N_PHI_D), dtype=torch.float32,
                          device=mapped.device)
    else:
        check_tables_out(out, count, mapped.device)
    if mapped.device.type == "cpu":  # the host decode, written into the tensor: the same steps, in fewer passes
        tables, slices = out.numpy(), mapped.detach().numpy()
        factors = [1.0] * count if scales is None else scales.detach().to(torch.float64).reshape(count).tolist()
        for i in range(count):
            table_from_mapped_host(slices[i], scale=factors[i], masked=masked, out=tables[i],  # type: ignore[arg-type]
                                   compiled=True)
        return out
    return _tables_by_tensor_steps(mapped, scales, fill, out)


def _tables_by_tensor_steps(mapped: torch.Tensor, scales: torch.Tensor | None, fill: float | None,
                            out: torch.Tensor) -> torch.Tensor:
    """The device branch of :func:`tables_from_mapped_tensor` (on any device; the CPU takes the host decode):
    :func:`unmap_kept_slices` in chunks of records, then the horizon mask's ``fill`` (None: kept)."""
    count = mapped.shape[0]
    constants = _constants(mapped.device)
    factors = constants["stored"].expand(count, N_CHANNELS).clone()
    if scales is not None:
        factors *= scales.to(mapped.device, torch.float64).reshape(count, 1)
    kept = mapped.reshape(count, N_CHANNELS, N_KEPT_SLICES, N_THETA_H, N_THETA_D).permute(0, 1, 3, 4, 2)
    for start in range(0, count, _DEVICE_CHUNK):
        records = slice(start, start + _DEVICE_CHUNK)
        unmap_kept_slices(kept[records], factors[records], out[records])
    if fill is not None:
        out.masked_fill_(constants["invalid"], fill)
    return out


@functools.cache
def _invalid_bins() -> np.ndarray:
    """Below-horizon bins of one channel, (90, 90, 180) bool, read-only."""
    invalid = ~horizon_mask()
    invalid.setflags(write=False)
    return invalid


def table_from_mapped_host(
    mapped: npt.NDArray[np.float32],
    *,
    scale: float = 1.0,
    masked: MaskedEntries = "unmeasured",
    out: npt.NDArray[np.float32] | None = None,
    compiled: bool = False,
) -> npt.NDArray[np.float32]:
    """One full table in stored MERL units from clamped mapped slices, as a NumPy array (the host decode).

    :func:`~brdfcodec.representation.network_io.table_from_mapped` followed by the mask, in fewer passes: the
    float64 exponentials (one per kept slice, one per gap) are taken with a vectorised ``exp``: NumPy's where it
    runs on AVX-512 lanes, over θh rows on the codec's threads, else torch's on its threads (NumPy's is scalar
    there: it was 40 % of a decode); the steps through each gap and the one rounding to float32 are NumPy's
    (:func:`~brdfcodec.representation.network_io.stepped_table`), with the below-horizon bins filled while each
    block is in cache (compiled: gaps wholly below the horizon filled, not stepped). The same operations in the
    same order as ``table_from_mapped``: equal to it up to the last bit of the float64 ``exp`` of each library
    (``spec/bvae-format.md`` §9; bit for bit where NumPy's is taken).

    Parameters
    ----------
    mapped : ndarray of float32, shape (63, 90, 90)
        Clamped mapped slices (network layout), values in ``[0, MAPPED_MAX]``.
    scale : float, default 1.0
        Factor ≥ 0 on reflectance (the energy bound, ``spec/bvae-format.md`` §6 step 5), applied to the
        interpolated table.
    masked : {"unmeasured", "zero", "keep"}, default "unmeasured"
        Below-horizon bins: −1, 0, or the decoded value.
    out : ndarray of float32, shape (3, 90, 90, 180), optional
        Where to write the table (C-contiguous; a CPU tensor's ``.numpy()``, say); a new array by default.
    compiled : bool, default False
        The passes before and after the exponentials compiled (:mod:`~brdfcodec.representation.stepped_kernel`,
        Numba), bit for bit the same table, faster, each pass's θh rows split over the codec's threads
        (:func:`~brdfcodec.representation.network_io.over_theta_h_rows`); the batch decodes ask for them (their
        first use in a process imports Numba: a one-time cost in time and memory).

    Returns
    -------
    ndarray of float32, shape (3, 90, 90, 180)
        Finite; ≥ 0 above the horizon. ``out`` when given.
    """
    fill = _mask_fill(masked)
    value = float(scale)
    if not (np.isfinite(value) and value >= 0.0):
        raise ValueError(f"scale must be a finite factor ≥ 0 on reflectance, got {scale!r}")
    array = np.asarray(mapped)
    if array.shape != (N_CHANNELS * N_KEPT_SLICES, N_THETA_H, N_THETA_D):
        raise ValueError(f"mapped must have shape ({N_CHANNELS * N_KEPT_SLICES}, {N_THETA_H}, {N_THETA_D}), "
                         f"got {array.shape}")
    factor = _STORED_PER_EXPM1 * value
    arguments = compiled_log_arguments() if compiled else None
    with torch.no_grad():
        if arguments is not None:  # x = L · m and (x_b − x_a) / n in one compiled pass, the same operations
            start, ratio = _scratch()
            over_theta_h_rows(arguments, np.ascontiguousarray(array, dtype=np.float32).reshape(
                N_CHANNELS, N_KEPT_SLICES, N_THETA_H, N_THETA_D), LOG_RANGE, _GAP_LENGTHS, start, ratio)
        else:
            kept = torch.from_numpy(np.require(array, np.float32, ("C", "W"))).view(
                N_CHANNELS, N_KEPT_SLICES, N_THETA_H, N_THETA_D).permute(0, 2, 3, 1)
            x = torch.empty((N_CHANNELS, N_THETA_H, N_THETA_D, N_KEPT_SLICES), dtype=torch.float64)
            x.copy_(kept).mul_(LOG_RANGE)  # x = L · m, kept slice last
            gaps = torch.sub(x[..., 1:], x[..., :-1]).div_(_constants(torch.device("cpu"))["steps"])
            start, ratio = x.numpy(), gaps.numpy()
        _exponentials_in_place(start, ratio, factor)
    return stepped_table(start, ratio, factor,
                         invalid=None if fill is None else _invalid_bins(), fill=fill or 0.0, out=out,
                         compiled=compiled)


@functools.cache
def _numpy_exp_is_vectorised() -> bool:
    """Whether NumPy's float64 ``exp`` runs on SIMD lanes on this CPU (its AVX-512F loop, faster than torch's
    on one thread); elsewhere NumPy's is scalar and torch's (Sleef, vectorised on every CPU) is taken."""
    try:
        from numpy._core._multiarray_umath import __cpu_features__
    except ImportError:  # pragma: no cover - a NumPy without the module: torch's exp
        return False
    return bool(__cpu_features__.get("AVX512F", False))


def _exponentials_in_place(start: np.ndarray, ratio: np.ndarray, factor: np.ndarray) -> None:
    """``start ← factor_c · exp(start)`` and ``ratio ← exp(ratio)`` in place (float64, (3, 90, 90, 21) and
    (3, 90, 90, 20)), with one library's ``exp`` per machine (:func:`_numpy_exp_is_vectorised`) whichever path
    calls, so that the batch and single decodes give the same bits. NumPy's runs over θh rows on the codec's
    threads (it releases the GIL, :func:`over_theta_h_rows`); torch's on its own."""
    scale = factor.reshape(N_CHANNELS, 1, 1, 1)
    if not _numpy_exp_is_vectorised():
        torch.from_numpy(ratio).exp_()
        torch.from_numpy(start).exp_().mul_(torch.from_numpy(scale))
        return

    def rows(first: int, stop: int) -> None:
        part = ratio[:, first:stop]
        np.exp(part, out=part)
        part = start[:, first:stop]
        np.exp(part, out=part)
        np.multiply(part, scale, out=part)

    over_theta_h_rows(rows)


_SCRATCH = threading.local()


def _scratch() -> tuple[np.ndarray, np.ndarray]:
    """This thread's float64 working arrays of the compiled host passes (x at the kept slices, and the gaps'
    arguments), reused from table to table: a new pair per table cost its page faults."""
    arrays = getattr(_SCRATCH, "arrays", None)
    if arrays is None:
        arrays = (np.empty((N_CHANNELS, N_THETA_H, N_THETA_D, N_KEPT_SLICES), dtype=np.float64),
                  np.empty((N_CHANNELS, N_THETA_H, N_THETA_D, N_KEPT_SLICES - 1), dtype=np.float64))
        _SCRATCH.arrays = arrays
    return arrays


def _mask_fill(masked: str) -> float | None:
    if masked == "keep":
        return None
    if masked not in ("unmeasured", "zero"):
        raise ValueError(f"masked must be 'unmeasured', 'zero' or 'keep', got {masked!r}")
    return float(UNMEASURED_VALUE) if masked == "unmeasured" else 0.0


def _network_mapped(decoder: BrdfDecoder, codes: torch.Tensor, batch_size: int) -> torch.Tensor:
    """Clamped network output (B, 63, 90, 90) float32 of codes, on the decoder's device."""
    if not len(codes):
        return torch.empty((0, N_CHANNELS * N_KEPT_SLICES, N_THETA_H, N_THETA_D), device=decoder.device)
    outputs = []
    with _EvalMode(decoder.network):  # under the caller's no_grad (inference tensors refuse the in-place clamp)
        for batch in network_batches(decoder, len(codes), batch_size):
            outputs.append(decoder.network(codes[batch].to(decoder.dtype)).float())
    return clamp_mapped_tensor(torch.cat(outputs) if len(outputs) > 1 else outputs[0])


def network_batches(decoder: BrdfDecoder, count: int, batch_size: int) -> list[slice]:
    """The batches in which the batched decodes run ``count`` codes through the network: ``batch_size`` codes at
    a time, each split into :meth:`BrdfDecoder.network_batch` ``(batch_size)`` codes (on the CPU, pairs; the
    last of a group of odd size alone): the network's output depends on the batch in its last bits, so every
    batched decode takes the same ones."""
    step = decoder.network_batch(batch_size)
    return [slice(low, min(low + step, group + batch_size, count))
            for group in range(0, count, batch_size) for low in range(group, min(group + batch_size, count), step)]


class _EvalMode:
    """Puts a module and its submodules in evaluation mode for a ``with`` block and restores each one's mode
    after; a module already wholly in evaluation mode is left alone (a mode switch walks every submodule)."""

    def __init__(self, module: torch.nn.Module) -> None:
        self.module = module
        self.training: list[torch.nn.Module] = []

    def __enter__(self) -> None:
        self.training = [module for module in self.module.modules() if module.training]
        for module in self.training:
            module.training = False

    def __exit__(self, *exc: object) -> None:
        for module in self.training:
            module.training = True


def _codes_tensor(decoder: BrdfDecoder, codes: torch.Tensor | npt.ArrayLike) -> torch.Tensor:
    """Latent codes (B, latent_dim) as float32 on the decoder's device; ValueError for a bad shape or value."""
    if isinstance(codes, np.ndarray) and not codes.flags.writeable:
        codes = codes.copy()  # torch warns on read-only arrays (records' codes are)
    tensor = torch.as_tensor(codes, dtype=torch.float32, device=decoder.device)
    if tensor.ndim != 2 or tensor.shape[-1] != decoder.latent_dim:
        raise ValueError(f"codes must have shape (B, {decoder.latent_dim}), got {tuple(tensor.shape)}")
    if not bool(torch.isfinite(tensor).all()):
        raise ValueError("latent codes must be finite")
    return tensor


def _is_plain_latent(record: Record) -> bool:
    """Whether a record's base is the network's decode of its one latent (batched on the device, in the same
    batches as :meth:`BrdfDecoder.decode_many`'s, so that both see the same network output); an edit is one too,
    its slices then take the highlight guard (``spec/bvae-format.md`` §6 step 6)."""
    from brdfcodec.codec.projection import _has_latent, _projected_vectors

    return isinstance(record, LatentRecord) and not _projected_vectors(record) and _has_latent(record)


def _guard_edit(mapped: torch.Tensor) -> None:
    """The highlight guard of an edited record's clamped mapped slices (63, 90, 90), in place (§6 step 6; the
    NumPy guard's running maximum, on the host: edits are few)."""
    guarded = guard_highlight(mapped.cpu().numpy())
    mapped.copy_(torch.from_numpy(np.ascontiguousarray(guarded)).to(mapped.device))


def _records_mapped(decoder: BrdfDecoder, records: Sequence[Record], batch_size: int) -> torch.Tensor:
    """Clamped mapped slices (N, 63, 90, 90) of records on the decoder's device (layers added, §4.4)."""
    plain = [i for i, record in enumerate(records) if _is_plain_latent(record)]
    on_network = set(plain)
    codes = _codes_tensor(decoder, np.stack([np.asarray(records[i].mu, dtype=np.float32) for i in plain])) \
        if plain else None
    if len(plain) == len(records):  # all from the network (the usual case): its output is the result, no copy
        mapped = _network_mapped(decoder, codes, batch_size)  # type: ignore[arg-type]
    else:
        mapped = torch.empty((len(records), N_CHANNELS * N_KEPT_SLICES, N_THETA_H, N_THETA_D), device=decoder.device)
        if codes is not None:
            mapped[plain] = _network_mapped(decoder, codes, batch_size)
    for i, record in enumerate(records):
        if i in on_network:
            residuals = decoder._layer_residuals(record)  # host: basis sum, inverse DCT (empty without layers)
            if residuals:
                for residual in residuals:
                    mapped[i] += torch.from_numpy(residual).to(decoder.device)
                clamp_mapped_tensor(mapped[i])
            if "edit" in record.meta:
                _guard_edit(mapped[i])
        else:  # grafts, projected bases, records without a latent: the NumPy path's mapped slices
            mapped[i] = torch.from_numpy(decoder._mapped_record(record)).to(decoder.device)
    return mapped


def decode_many_tensor(
    decoder: BrdfDecoder,
    records: Sequence[Record] | torch.Tensor | npt.ArrayLike,
    *,
    masked: MaskedEntries = "unmeasured",
    energy_bound: bool | None = None,
    batch_size: int = 16,
    out: torch.Tensor | None = None,
) -> torch.Tensor:
    """:meth:`BrdfDecoder.decode_many_tensor <brdfcodec.codec.BrdfDecoder.decode_many_tensor>` (see there)."""
    if batch_size < 1:
        raise ValueError(f"batch_size must be at least 1, got {batch_size}")
    _mask_fill(masked)  # a bad value is refused before any work
    given, codes, count = records_or_codes(decoder, records)
    if out is not None:  # refused before any work
        check_tables_out(out, count, decoder.device)
    if count == 0:
        return out if out is not None else torch.empty((0, N_CHANNELS, N_THETA_H, N_THETA_D, N_PHI_D),
                                                       device=decoder.device)
    for record in given or ():  # every record refused before any work
        decoder._check_record(record)
    if out is None:
        out = torch.empty((count, N_CHANNELS, N_THETA_H, N_THETA_D, N_PHI_D), dtype=torch.float32,
                          device=decoder.device)
    with codec_threads(), torch.no_grad():
        # ``batch_size`` records at a time, as decode_many takes them (so that the network sees the same batches:
        # BrdfDecoder.network_batch), unmapped into their rows of ``out``: the mapped slices of all records are
        # never held at once
        for start in range(0, count, batch_size):
            part = slice(start, min(start + batch_size, count))
            mapped, scales = _mapped_and_scales(decoder, None if given is None else given[part],
                                                None if codes is None else codes[part], energy_bound, batch_size)
            tables_from_mapped_tensor(mapped, scales, masked=masked, out=out[part])
        return out


def records_or_codes(
    decoder: BrdfDecoder, records: Sequence[Record] | torch.Tensor | npt.ArrayLike,
) -> tuple[list[Record] | None, torch.Tensor | None, int]:
    """What the batch decodes were given: ``(records, None, N)`` for a sequence of records, ``(None, codes, N)``
    for latent codes (checked: shape (N, latent_dim), finite; on the decoder's device), ``(None, None, 0)`` for
    an empty sequence.

    Raises
    ------
    TypeError
        A sequence that mixes records with anything else.
    ValueError
        Codes of the wrong shape or not finite.
    """
    given = list(records) if isinstance(records, Sequence) and not isinstance(records, str | bytes) else None
    if given is not None and not given:
        return None, None, 0
    if given is not None and any(isinstance(r, Record) for r in given):
        if not all(isinstance(r, Record) for r in given):
            raise TypeError("records must be a sequence of records, or latent codes of shape (B, latent_dim)")
        return given, None, len(given)
    codes = _codes_tensor(decoder, records)
    return None, codes, len(codes)


def _mapped_and_scales(
    decoder: BrdfDecoder, records: Sequence[Record] | None, codes: torch.Tensor | None, energy_bound: bool | None,
    batch_size: int,
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Clamped mapped slices (N, 63, 90, 90) of records (or of codes, when ``records`` is None) on the decoder's
    device, and the energy bound's factors (N,) float64 where a table takes it (None where none does).

    By default the bound is for edits (records whose metadata holds "edit": ``decoder.is_edited``), never for codes.
    """
    if records is not None:
        for record in records:
            decoder._check_record(record)
        mapped = _records_mapped(decoder, records, batch_size)
        bounded = [energy_bound if energy_bound is not None else "edit" in r.meta for r in records]
    else:
        assert codes is not None
        mapped = _network_mapped(decoder, codes, batch_size)
        bounded = [bool(energy_bound)] * len(mapped)
    scales = None
    if any(bounded):
        scales = torch.ones(len(mapped), dtype=torch.float64, device=mapped.device)
        chunk = _CPU_CHUNK if mapped.device.type == "cpu" else _DEVICE_CHUNK
        which = [i for i, bound in enumerate(bounded) if bound]
        for start in range(0, len(which), chunk):
            part = which[start : start + chunk]
            scales[part] = energy_bound_scales_tensor(mapped[part])
    return mapped, scales
