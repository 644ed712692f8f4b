"""Decoded materials evaluated at direction pairs on the decoder's device, without full tables (issue 51, item 1).

Part of :mod:`brdfcodec.codec`; reached through :meth:`BrdfDecoder.evaluate_tensor
<brdfcodec.codec.BrdfDecoder.evaluate_tensor>`.

A renderer that needs a material's value at a few directions, not its 17.5 MB table, asks for them here: each
direction pair is turned into its MERL bin (the nearest-bin lookup of ``spec/conventions.md`` §3, as
:func:`~brdfcodec.representation.lookup.lookup` and MERL's reader do), and only that bin of the table is made from
the network's 21 kept φd slices — the two kept slices around the bin's φd, interpolated and unmapped as
``spec/bvae-format.md`` §6 step 2 says (float64), times the energy bound's factor where the table takes it.
So a value equals the same bin of :meth:`BrdfDecoder.decode_many`'s table up to float32 rounding (and of a GPU's
:meth:`BrdfDecoder.decode_many_tensor` table within its 1e-6 mapped), and the work and memory grow with the
directions asked for, not with the table. The angles are computed in float64 on the device, in the operations of
:func:`~brdfcodec.representation.coords.half_diff_from_directions` and the bin functions beside it; a pair is above
the horizon as :func:`~brdfcodec.representation.lookup.lookup` decides it, on the vectors as given.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import numpy.typing as npt
import torch

from brdfcodec.conventions import (
    BIN_TOLERANCE,
    HORIZON_COS_MIN,
    N_CHANNELS,
    N_KEPT_SLICES,
    N_PHI_D,
    N_THETA_D,
    N_THETA_H,
)
from brdfcodec.format.bvae import Record
from brdfcodec.representation.layout import interpolation_plan
from brdfcodec.representation.mapping import LOG_RANGE

if TYPE_CHECKING:
    from brdfcodec.codec.device_decode import BrdfDecoder

__all__ = ["evaluate_tensor", "merl_bins_tensor"]


@functools.cache
def _plan_on(device: torch.device) -> dict[str, torch.Tensor]:
    """Per-device interpolation plan: each φd bin's two kept slots and the right one's weight."""
    left, right, weight = interpolation_plan()
    return {
        "left": torch.from_numpy(left.astype(np.int64)).to(device),
        "right": torch.from_numpy(right.astype(np.int64)).to(device),
        "weight": torch.from_numpy(weight.astype(np.float64)).to(device),
    }


def _directions(values: torch.Tensor | npt.ArrayLike, label: str, device: torch.device) -> torch.Tensor:
    """Direction vectors (..., 3) as float64 on ``device``: finite and non-zero (any length)."""
    if isinstance(values, np.ndarray) and not values.flags.writeable:
        values = values.copy()  # torch warns on read-only arrays (np.broadcast_to gives them)
    tensor = torch.as_tensor(values, dtype=torch.float64, device=device)
    if tensor.ndim == 0 or tensor.shape[-1] != 3:
        raise ValueError(f"{label} must hold 3-vectors, shape (..., 3), got shape {tuple(tensor.shape)}")
    if not bool(torch.isfinite(tensor).all()):
        raise ValueError(f"{label} holds NaN or infinite components")
    if not bool((tensor != 0).any(dim=-1).all()):
        raise ValueError(f"{label} holds zero vectors (a direction needs a length > 0)")
    return tensor


def _normalized(v: torch.Tensor) -> torch.Tensor:
    return v / torch.linalg.vector_norm(v, dim=-1, keepdim=True)


def _bin(coordinate: torch.Tensor, n: int) -> torch.Tensor:
    return torch.floor(coordinate + BIN_TOLERANCE).to(torch.int64).clamp_(0, n - 1)


def merl_bins_tensor(wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """MERL bins (θh, θd, φd indices) of direction pairs and whether both lie above the horizon.

    Parameters
    ----------
    wi, wo : torch.Tensor of float64, shape (..., 3)
        Directions in the shading frame (z = normal), any finite non-zero length, broadcast together.

    Returns
    -------
    tuple of torch.Tensor
        ``theta_h``, ``theta_d``, ``phi_d`` bin indices (int64, in [0, 89], [0, 89], [0, 179]) and ``above``
        (bool), each of the broadcast shape without its last axis.
    """
    above = (wi[..., 2] > HORIZON_COS_MIN) & (wo[..., 2] > HORIZON_COS_MIN)  # on the vectors as given, as lookup
    wi, wo = torch.broadcast_tensors(_normalized(wi), _normalized(wo))
    above = above.expand(wi.shape[:-1])
    half = _normalized(wi + wo)
    theta_h = torch.atan2(torch.hypot(half[..., 0], half[..., 1]), half[..., 2])  # accurate near 0, unlike acos
    phi_h = torch.atan2(half[..., 1], half[..., 0])
    # d = wi rotated by −φh about z, then by −θh about y (representation/coords.py)
    cos_p, sin_p = torch.cos(-phi_h), torch.sin(-phi_h)
    x = cos_p * wi[..., 0] - sin_p * wi[..., 1]
    y = sin_p * wi[..., 0] + cos_p * wi[..., 1]
    z = wi[..., 2]
    cos_t, sin_t = torch.cos(-theta_h), torch.sin(-theta_h)
    dx, dz = cos_t * x + sin_t * z, -sin_t * x + cos_t * z
    theta_d = torch.atan2(torch.hypot(dx, y), dz)
    phi_d = torch.atan2(y, dx)
    half_pi = math.pi / 2
    h_index = _bin(N_THETA_H * torch.sqrt(theta_h.clamp(min=0.0) / half_pi), N_THETA_H)
    d_index = _bin(N_THETA_D * theta_d.clamp(min=0.0) / half_pi, N_THETA_D)
    folded = torch.remainder(phi_d, math.pi)
    folded = torch.where(folded >= math.pi, torch.zeros_like(folded), folded)
    p_index = torch.remainder(_bin(N_PHI_D * folded / math.pi, N_PHI_D + 1), N_PHI_D)
    return h_index, d_index, p_index, above


def evaluate_tensor(
    decoder: BrdfDecoder,
    records: Sequence[Record] | torch.Tensor | npt.ArrayLike,
    wi: torch.Tensor | npt.ArrayLike,
    wo: torch.Tensor | npt.ArrayLike,
    *,
    energy_bound: bool | None = None,
    batch_size: int = 16,
) -> torch.Tensor:
    """:meth:`BrdfDecoder.evaluate_tensor <brdfcodec.codec.BrdfDecoder.evaluate_tensor>` (see there)."""
    from brdfcodec.codec.device_decode import _mapped_and_scales, records_or_codes
    from brdfcodec.runtime.threads import codec_threads

    if batch_size < 1:
        raise ValueError(f"batch_size must be at least 1, got {batch_size}")
    device = decoder.device
    incoming, outgoing = _directions(wi, "wi", device), _directions(wo, "wo", device)
    try:
        shape = torch.broadcast_shapes(incoming.shape, outgoing.shape)
    except RuntimeError:
        raise ValueError(f"wi and wo do not broadcast together: shapes {tuple(incoming.shape)} and "
                         f"{tuple(outgoing.shape)}") from None
    given, codes, count = records_or_codes(decoder, records)
    for record in given or ():  # every record refused before any work
        decoder._check_record(record)
    lead = tuple(shape[:-1])
    if len(lead) > 2 or (len(lead) == 2 and lead[0] not in (1, count)):
        raise ValueError(f"directions must have shape (N, 3), or (B, N, 3) with B = {count} materials; "
                         f"got shape {tuple(shape)}")
    directions = lead[-1] if lead else 1
    if count == 0:
        return torch.empty((0, directions, N_CHANNELS), dtype=torch.float32, device=device)
    rows = lead[0] if len(lead) == 2 else 1
    incoming = incoming.expand(shape).reshape(rows, directions, 3)
    outgoing = outgoing.expand(shape).reshape(rows, directions, 3)
    with codec_threads(), torch.no_grad():
        lookup = _lookup(*merl_bins_tensor(incoming, outgoing))
        # ``batch_size`` materials at a time, as decode_many takes them (the network sees the same batches): their
        # mapped slices are looked up and dropped, never all held at once
        values = []
        for start in range(0, count, batch_size):
            part = slice(start, min(start + batch_size, count))
            mapped, scales = _mapped_and_scales(decoder, None if given is None else given[part],
                                                None if codes is None else codes[part], energy_bound, batch_size)
            values.append(_values_at(mapped, scales, lookup if rows == 1 else _Lookup(*(t[part] for t in lookup))))
        return torch.cat(values) if len(values) > 1 else values[0]


class _Lookup(NamedTuple):
    """Where :func:`evaluate_tensor` reads (B or 1, N) direction pairs: the flat indices (…, N·3) of the kept
    slots on either side in a material's (63, 90, 90) slices, per channel; the interpolation weight (…, N, 1)
    float64; whether the pair is measured (above the horizon and a valid bin)."""

    low: torch.Tensor
    high: torch.Tensor
    weight: torch.Tensor
    keep: torch.Tensor


def _lookup(h: torch.Tensor, d: torch.Tensor, p: torch.Tensor, above: torch.Tensor) -> _Lookup:
    """The :class:`_Lookup` of the MERL bins ``h, d, p`` and horizon flags ``above`` of :func:`merl_bins_tensor`
    ((B or 1, N)): computed once per call, whatever the number of materials."""
    from brdfcodec.codec.device_decode import _constants

    device = h.device
    plan = _plan_on(device)
    channel = torch.arange(N_CHANNELS, device=device) * N_KEPT_SLICES  # (3,)
    cell = (h * N_THETA_D + d)[..., None]  # (…, N, 1)
    plane = N_THETA_H * N_THETA_D
    rows = h.shape[0]
    low = ((channel + plan["left"][p][..., None]) * plane + cell).reshape(rows, -1)
    high = ((channel + plan["right"][p][..., None]) * plane + cell).reshape(rows, -1)
    keep = above & ~_constants(device)["invalid"][h, d, p]
    return _Lookup(low, high, plan["weight"][p][..., None], keep)


def _values_at(mapped: torch.Tensor, scales: torch.Tensor | None, lookup: _Lookup) -> torch.Tensor:
    """Stored values (B, N, 3) float32 of B materials' clamped mapped slices ``mapped`` (B, 63, 90, 90) where
    ``lookup`` reads, times the energy bound's factors ``scales`` (B,) where given: the kept slots on either side
    interpolated in the mapped domain, unmapped in float64, 0 below the horizon."""
    from brdfcodec.codec.device_decode import _constants

    count = len(mapped)
    directions = lookup.keep.shape[-1]
    flat = mapped.reshape(count, -1)
    low = flat.gather(1, lookup.low.expand(count, -1)).reshape(count, directions, N_CHANNELS).double()
    high = flat.gather(1, lookup.high.expand(count, -1)).reshape(count, directions, N_CHANNELS).double()
    t = lookup.weight
    x = ((1.0 - t) * low + t * high) * LOG_RANGE  # the interpolated argument (float64)
    factor = _constants(mapped.device)["stored"].reshape(1, 1, N_CHANNELS)
    if scales is not None:
        factor = factor * scales.reshape(count, 1, 1)
    value = torch.expm1(x) * factor
    return torch.where(lookup.keep[..., None], value, torch.zeros_like(value)).float()
