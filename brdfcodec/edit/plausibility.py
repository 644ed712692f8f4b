"""Plausibility of decodes along latent traversals (issue 12, item 5).

For every material of a library and every latent dimension d, the decoder is
run at ``μ + t·e_d`` for t in ``steps`` (prior σ units, as
:func:`brdfcodec.edit.latent_edits.traverse` does) and each decode is checked against the
source decode at μ and against the library:

``invalid``
    Some decoded value above the horizon is non-finite or negative (stored
    MERL units, the kept φd bins of :meth:`~brdfcodec.codec.BrdfDecoder.decode`;
    the φd interpolation is convex, so the other bins lie between them).
``inverted``
    An *inverted specular peak* that the source did not have. For colour c,
    kept φd slot s and θd bin j, the cell's *specular deficit* is

    .. math::

        D = \\max_{θ_h \\in \\{4, 5, 6\\}} m[c, s, θ_h, j] - \\max_{θ_h \\in \\{0, 1\\}} m[c, s, θ_h, j]

    in mapped units m (``spec/conventions.md`` §4; θh bins 0–1 span θh < 0.045°,
    bins 4–6 span 0.18–0.54°). A cell is inverted when D exceeds the
    tolerance τ (default 0.1 mapped units, a factor 101^0.1 ≈ 1.6 in ρ/ε + 1).
    Every θd bin 0–89 counts where the five entries are above the horizon at
    that slot. A decode is flagged when some cell is inverted and the same
    cell of the source decode is not.
``inverted_wide``
    An *inverted highlight* as the judge of issue 50 sees it, on the decoded
    table (stored units, the kept φd bins, where the table is exactly the
    decoded slices): in some column (colour, θd bin, kept φd bin) the
    specular peak, the largest value at θh < 2° (bins 0–13,
    :data:`JUDGE_PEAK_BINS`), is darker than ``JUDGE_RATIO`` (½) of the body,
    the mean at θh 40–60° (bins 60–73, :data:`JUDGE_BODY_BINS`), where the
    source decode's peak in that column is not (:func:`inverted_highlights`).
    The ratio does not depend on the energy bound's factor. ``inverted`` is the
    narrower, older figure (bins 0–1 against 4–6), kept beside it.
``energetic``
    The decode's white-sky albedo (:func:`white_sky_albedo`, largest channel)
    exceeds the largest over the library's μ decodes by more than the
    relative margin (default 10 %).
``unphysical``
    The decode's directional albedo (:func:`brdfcodec.representation.energy.directional_albedo_mapped`)
    exceeds 1 (by more than 1e-4) at some incident elevation and channel: lit
    from that direction it reflects more light than it receives.
``holes``
    Some near-specular entry (θh bins 0–1, above the horizon) decodes to
    exactly 0 (the decoder's output was clamped at the floor of the mapped
    domain) while the off-specular flank of its cell (θh bins 4–6) is above
    0, where the source decode was above 0: the "black hole" of issue 12.
``pits``
    A *pit* in the highlight that the source did not have: in some cell,
    a value at θh bin i below 20 falls more than τ below the largest value at
    bins i + 1 to 20 (θh below 4.4°; entries above the horizon only,
    :func:`pit_cells`). It sees what ``inverted`` and ``holes``, which compare
    bins 0–1 with 4–6 only, miss: a centre that goes dark over a wider disc,
    the black dot a traversal sheet shows.

By default the traversal decodes are judged as an editor shows them: with the
energy bound of ``spec/bvae-format.md`` §6.3 (a decode whose directional
albedo exceeds 1 is scaled down to 1), so ``unphysical`` checks that the bound
holds; ``energy_bound=False`` judges the network's raw decodes. ``highlight_guard=True`` applies the
highlight guard of edited records first (``spec/bvae-format.md`` §6 step 6,
:mod:`brdfcodec.representation.highlight_guard`), as edits decode since revision 2.5; the default judges the
network's decodes without it, which is what a training objective has to fix.

Examples
--------
>>> import numpy as np
>>> mapped = np.full((63, 90, 90), 0.5, dtype=np.float32)
>>> specular_deficit(mapped).shape          # colour, kept slot, θd bin
(3, 21, 90)
>>> float(np.nanmax(specular_deficit(mapped)))
0.0
>>> mapped[21 + 10, 0:2, 10] = 0.2          # green, slot 10 (φd bin 90), θd bin 10: peak below its flank
>>> bool(inverted_cells(mapped)[1, 10, 10]), int(inverted_cells(mapped).sum())
(True, 1)
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import (
    EPSILON,
    KEPT_PHI_D_SLICES,
    N_CHANNELS,
    N_KEPT_SLICES,
    N_PHI_D,
    N_THETA_D,
    N_THETA_H,
    NETWORK_INPUT_SHAPE,
)
from brdfcodec.representation.energy import bound_scales, directional_albedo_mapped, scale_mapped
from brdfcodec.representation.highlight import (
    NEAR_THETA_H_BINS,
    OFF_THETA_H_BINS,
    PIT_THETA_H_BINS,
    cell_valid_mask,
    outer_maximum,
    window_valid_mask,
)
from brdfcodec.representation.highlight_guard import guard_highlight
from brdfcodec.representation.mapping import LOG_RANGE

__all__ = [
    "DEFAULT_STEPS",
    "KINDS",
    "SUMMARY_KINDS",
    "NEAR_THETA_H_BINS",
    "OFF_THETA_H_BINS",
    "Offender",
    "PlausibilityCriteria",
    "PlausibilityReport",
    "UNPHYSICAL_TOLERANCE",
    "albedo_weights",
    "bounded",
    "cell_valid_mask",
    "entry_valid_mask",
    "inverted_cells",
    "inverted_highlights",
    "JUDGE_BODY_BINS",
    "JUDGE_PEAK_BINS",
    "JUDGE_RATIO",
    "peak_body",
    "measure_plausibility",
    "new_holes",
    "pit_cells",
    "pit_depth",
    "plausible_range",
    "specular_deficit",
    "white_sky_albedo",
]

#: Traversal offsets, prior σ units.
DEFAULT_STEPS: tuple[float, ...] = (-3.0, -2.0, -1.0, 1.0, 2.0, 3.0)
#: How far above 1 a directional albedo may be before ``unphysical`` flags it (float32 rounding of the bound).
UNPHYSICAL_TOLERANCE = 1e-4
#: The kinds of implausibility, in report order.
KINDS: tuple[str, ...] = ("invalid", "inverted", "inverted_wide", "energetic", "unphysical", "holes", "pits")
#: θh bins of the judge's specular peak (issue 50): θh < 2°, bins 0–13 by the MERL index ⌊90·√(θh/90°)⌋.
JUDGE_PEAK_BINS: tuple[int, ...] = tuple(range(0, 14))
#: θh bins of the judge's body: θh 40–60°, bins 60–73.
JUDGE_BODY_BINS: tuple[int, ...] = tuple(range(60, 74))
#: A peak darker than this fraction of the body is inverted.
JUDGE_RATIO = 0.5
#: Unions of kinds that a report counts too: ``highlight`` (inverted or holes, a broken highlight) and ``any``.
SUMMARY_KINDS: tuple[str, ...] = ("highlight", "any")

FloatArray = npt.NDArray[np.floating]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class PlausibilityCriteria:
    """Thresholds of the checks (see the module docstring).

    Parameters
    ----------
    inversion_tolerance : float, default 0.1
        τ, mapped units: a cell is inverted when its specular deficit exceeds it.
        Over the 90 μ decodes of the shipped library with the default model no
        deficit reaches the default (``bvae model plausibility``).
    energy_margin : float, default 0.1
        Relative margin over the library's largest white-sky albedo.
    """

    inversion_tolerance: float = 0.1
    energy_margin: float = 0.1

    def __post_init__(self) -> None:
        if not (np.isfinite(self.inversion_tolerance) and self.inversion_tolerance >= 0):
            raise ValueError(f"inversion_tolerance must be finite and ≥ 0, got {self.inversion_tolerance}")
        if not (np.isfinite(self.energy_margin) and self.energy_margin >= 0):
            raise ValueError(f"energy_margin must be finite and ≥ 0, got {self.energy_margin}")


def _split(mapped: npt.ArrayLike) -> np.ndarray:
    """(..., 63, 90, 90) network layout as (..., 3, 21, θh 90, θd 90)."""
    array = np.asarray(mapped)
    if array.shape[-3:] != NETWORK_INPUT_SHAPE:
        raise ValueError(f"expected mapped slices of shape (..., {NETWORK_INPUT_SHAPE}), got {array.shape}")
    return array.reshape(*array.shape[:-3], N_CHANNELS, N_KEPT_SLICES, N_THETA_H, N_THETA_D)


@functools.cache
def entry_valid_mask() -> BoolArray:
    """(21, θh 90, θd 90): entries of one colour block that are above the horizon."""
    from brdfcodec.representation.mask import kept_slice_horizon_mask

    valid = np.ascontiguousarray(np.moveaxis(kept_slice_horizon_mask(), -1, 0))
    valid.setflags(write=False)
    return valid


def specular_deficit(mapped: npt.ArrayLike) -> FloatArray:
    """How far the near-specular peak falls below its off-specular flank, per cell.

    Parameters
    ----------
    mapped : array_like, shape (..., 63, 90, 90)
        Mapped slices in the network layout (:meth:`~brdfcodec.codec.BrdfDecoder.decode_mapped`).

    Returns
    -------
    ndarray, shape (..., 3, 21, 90)
        ``max(m[θh 4–6]) − max(m[θh 0–1])`` per colour, kept φd slot and θd bin,
        mapped units; NaN where a cell has an entry below the horizon. Positive:
        the flank is brighter than the peak.
    """
    blocks = _split(mapped)
    near = blocks[..., list(NEAR_THETA_H_BINS), :].max(axis=-2)
    off = blocks[..., list(OFF_THETA_H_BINS), :].max(axis=-2)
    deficit = (off - near).astype(np.result_type(blocks.dtype, np.float32), copy=False)
    return np.where(cell_valid_mask(), deficit, np.nan)


def inverted_cells(mapped: npt.ArrayLike, tolerance: float = 0.1) -> BoolArray:
    """Cells whose specular deficit exceeds ``tolerance`` (mapped units), shape (..., 3, 21, 90).

    Non-finite values count as inverted (a NaN peak is no peak); cells below the horizon never do.
    """
    deficit = specular_deficit(mapped)
    blocks = _split(mapped)
    rows = blocks[..., list(NEAR_THETA_H_BINS + OFF_THETA_H_BINS), :]
    broken = ~np.isfinite(rows).all(axis=-2) & cell_valid_mask()
    with np.errstate(invalid="ignore"):
        return (deficit > tolerance) | broken


@functools.cache
def _judge_valid(n_bins: int) -> BoolArray:
    """(θd 90, K): columns whose peak and body entries are all above the horizon; K = 21 (kept bins) or 180."""
    from brdfcodec.representation.mask import horizon_mask, kept_slice_horizon_mask

    mask = kept_slice_horizon_mask() if n_bins == N_KEPT_SLICES else horizon_mask()
    if mask.shape[-1] != n_bins:
        raise ValueError(f"expected tables of the 21 kept φd bins or all 180, got {n_bins} bins")
    valid = mask[list(JUDGE_PEAK_BINS + JUDGE_BODY_BINS)].all(axis=0)
    valid.setflags(write=False)
    return valid


def peak_body(table: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """The judge's specular peak and body of every column of decoded tables (issue 50).

    Parameters
    ----------
    table : array_like, shape (..., 3, 90, 90, K)
        Decoded tables in stored units (:meth:`~brdfcodec.codec.BrdfDecoder.decode`), K = 21 (the kept φd
        bins, in order) or 180.

    Returns
    -------
    peak, body : ndarray of float64, shape (..., 3, 90, K)
        Per colour, θd bin and φd bin: the largest value at θh < 2° and the mean at θh 40–60° (stored units);
        NaN where an entry of either lies below the horizon.
    """
    values = np.asarray(table, dtype=np.float64)
    valid = _judge_valid(values.shape[-1])
    peak = values[..., list(JUDGE_PEAK_BINS), :, :].max(axis=-3)
    body = values[..., list(JUDGE_BODY_BINS), :, :].mean(axis=-3)
    return np.where(valid, peak, np.nan), np.where(valid, body, np.nan)


def inverted_highlights(source: npt.ArrayLike, edited: npt.ArrayLike, ratio: float = JUDGE_RATIO) -> BoolArray:
    """Columns whose peak is darker than ``ratio`` × body in ``edited`` but not in ``source`` (issue 50's judge).

    Parameters
    ----------
    source : array_like, shape (3, 90, 90, K)
        The unedited decode's table (stored units).
    edited : array_like, shape (..., 3, 90, 90, K)
        Tables of edits of it.
    ratio : float, default 0.5

    Returns
    -------
    ndarray of bool, shape (..., 3, 90, K)
        Colour, θd bin, φd bin; False below the horizon. A non-finite edited peak or body counts as inverted.
    """
    src_peak, src_body = peak_body(source)
    peak, body = peak_body(edited)
    with np.errstate(invalid="ignore"):
        source_ok = src_peak >= ratio * src_body
        broken = ~(np.isfinite(peak) & np.isfinite(body)) & _judge_valid(np.shape(edited)[-1])
        return source_ok & ((peak < ratio * body) | broken)


def pit_depth(mapped: npt.ArrayLike) -> FloatArray:
    """How far each cell's highlight falls towards its centre: max over θh bins i < 20 above the horizon of
    (R_i − m_i), R_i the largest value at bins i + 1 to 20 above the horizon (mapped units), shape
    (..., 3, 21, 90); NaN where no such pair exists."""
    blocks = _split(mapped)
    outer = outer_maximum(mapped)
    inner = blocks[..., : PIT_THETA_H_BINS - 1, :]
    usable = np.isfinite(outer) & window_valid_mask()[:, :-1, :]
    with np.errstate(invalid="ignore"):
        depth = np.where(usable, outer - inner, -np.inf).max(axis=-2)
    depth = depth.astype(np.result_type(blocks.dtype, np.float32), copy=False)
    return np.where(np.isfinite(depth), depth, np.nan)


def pit_cells(mapped: npt.ArrayLike, tolerance: float = 0.1) -> BoolArray:
    """Cells whose :func:`pit_depth` exceeds ``tolerance`` (mapped units), shape (..., 3, 21, 90)."""
    with np.errstate(invalid="ignore"):
        return pit_depth(mapped) > tolerance


def new_holes(source: npt.ArrayLike, edited: npt.ArrayLike) -> BoolArray:
    """Holes in the highlight: near-specular zeros under a lit flank, where the source was above 0.

    An entry (θh bin 0 or 1, above the horizon) is a hole when the edited
    decode is 0 there (the decoder's output fell to the floor of the mapped
    domain and was clamped), the off-specular flank of its cell (θh bins 4–6)
    is still above 0, and the source decode was above 0 there. A region that
    goes black as a whole is not a hole.

    Parameters
    ----------
    source : array_like, shape (63, 90, 90)
        Mapped slices of the source decode.
    edited : array_like, shape (..., 63, 90, 90)
        Mapped slices of the edited decodes.

    Returns
    -------
    ndarray of bool, shape (..., 3, 21, 2, 90)
        Colour, kept slot, near θh bin, θd bin.
    """
    near = list(NEAR_THETA_H_BINS)
    src = _split(source)[..., near, :]
    blocks = _split(edited)
    out = blocks[..., near, :]
    flank = blocks[..., list(OFF_THETA_H_BINS), :].max(axis=-2)[..., None, :]
    valid = entry_valid_mask()[:, near, :]
    return (out <= 0) & (flank > 0) & (src > 0) & valid


@functools.cache
def albedo_weights() -> np.ndarray:
    """Quadrature weights (21, θh 90, θd 90) of :func:`white_sky_albedo` on the kept slices, 0 below the horizon."""
    from brdfcodec.representation.coords import directions_from_half_diff
    from brdfcodec.representation.mask import kept_slice_horizon_mask

    edges_h = (np.arange(N_THETA_H + 1) / N_THETA_H) ** 2 * (np.pi / 2)  # θh bin i spans [(i/90)², ((i+1)/90)²]·π/2
    edges_d = np.arange(N_THETA_D + 1) / N_THETA_D * (np.pi / 2)
    mid_h, mid_d = 0.5 * (edges_h[:-1] + edges_h[1:]), 0.5 * (edges_d[:-1] + edges_d[1:])
    kept = np.asarray(KEPT_PHI_D_SLICES)
    th, td, pd = np.meshgrid(mid_h, mid_d, kept * (np.pi / N_PHI_D), indexing="ij")
    wi, wo = directions_from_half_diff(th, td, pd)
    cosines = np.clip(wi[..., 2], 0, None) * np.clip(wo[..., 2], 0, None)  # (θh, θd, slot), at bin midpoints
    sin_dh = np.cos(edges_h[:-1]) - np.cos(edges_h[1:])  # ∫ sin θh dθh over the bin
    sin_dd = np.cos(edges_d[:-1]) - np.cos(edges_d[1:])
    gaps = np.diff(np.append(kept, N_PHI_D))  # φd is periodic over [0, π): slot 179 neighbours slot 0
    dphi = 0.5 * (gaps + np.roll(gaps, 1)) * (np.pi / N_PHI_D)  # trapezoid weight per kept slot
    # dωi dωo = 4 cos θd dωh dωd; φh gives 2π, φd over [0, 2π) folds onto [0, π) (factor 2); albedo = ∫∫ρ cos cos / π.
    weights = (4 * np.cos(mid_d)[None, :, None] * sin_dh[:, None, None] * sin_dd[None, :, None]
               * dphi[None, None, :] * cosines * (2 * np.pi * 2 / np.pi))
    weights = np.where(kept_slice_horizon_mask(), weights, 0.0)
    weights = np.ascontiguousarray(np.moveaxis(weights, -1, 0))
    weights.setflags(write=False)
    return weights


def white_sky_albedo(mapped: npt.ArrayLike) -> FloatArray:
    """Bi-hemispherical (white-sky) albedo ``(1/π) ∫∫ ρ cos θi cos θo dωi dωo`` per colour channel.

    Evaluated from the kept φd slices by quadrature on the MERL grid (the
    Rusinkiewicz Jacobian 4 cos θd, exact ∫ sin θ dθ per bin, cosines at bin
    midpoints, trapezoids in periodic φd; entries below the horizon weigh 0):
    a Lambertian BRDF of albedo a gives a (``tests/test_plausibility.py``). Energy
    conservation requires ≤ 1.

    Parameters
    ----------
    mapped : array_like, shape (..., 63, 90, 90)
        Mapped slices (clamped to the mapped domain).

    Returns
    -------
    ndarray of float64, shape (..., 3)
        Albedo per channel (R, G, B), dimensionless.
    """
    blocks = _split(mapped).astype(np.float64)
    reflectance = np.expm1(blocks * LOG_RANGE) * EPSILON  # physical 1/sr, the inverse of the log mapping
    return np.einsum("...cshd,shd->...c", reflectance, albedo_weights())


def _invalid_counts(mapped: np.ndarray) -> np.ndarray:
    """Per decode, how many above-horizon values at the kept φd bins are non-finite or negative (stored units)."""
    from brdfcodec.representation.mask import kept_slice_horizon_mask
    from brdfcodec.representation.network_io import table_from_mapped

    with np.errstate(invalid="ignore", over="ignore"):  # a NaN spreads over its row (0 · NaN): still one bad decode
        table = table_from_mapped(mapped, phi_d_bins=KEPT_PHI_D_SLICES)  # (B, 3, θh, θd, 21): the decode path
    bad = ~np.isfinite(table) | (table < 0)
    return (bad & kept_slice_horizon_mask()).reshape(len(mapped), -1).sum(axis=1)


@dataclass(frozen=True)
class Offender:
    """One implausible decode: which material, dimension (0-based) and step, and by how much.

    ``score`` depends on ``kind``: ``inverted``, the largest specular deficit
    (mapped units) among new inversions, at ``where`` = (colour, φd bin, θd bin); ``inverted_wide``, the
    number of columns the judge of issue 50 flags;
    ``holes``, the number of new zero entries near the peak; ``pits``, the largest new pit depth (mapped
    units); ``energetic``, the largest channel's
    white-sky albedo; ``unphysical``, the largest directional albedo; ``invalid``, the number of bad values.
    """

    material: str
    dim: int
    step: float
    kind: str
    score: float
    where: tuple[int, ...] = ()


@dataclass(frozen=True)
class PlausibilityReport:
    """Fractions of implausible decodes over a library's traversals.

    Attributes
    ----------
    materials : tuple of str
    dims : tuple of int
        Latent dimensions traversed (0-based; printed 1-based as z1 …).
    steps : tuple of float
        Offsets, prior σ units.
    fractions : dict of str to ndarray, shape (len(dims), len(steps))
        For each kind in :data:`KINDS`, ``"highlight"`` (inverted or holes: a broken highlight, the
        kinds issue 41 bounds together) and ``"any"``: the fraction of the library's materials whose decode
        at (dim, step) is flagged.
    source_inverted : float
        Fraction of the μ decodes that already have an inverted cell (these cells never count).
    albedo_limit : float
        The energy threshold: largest μ albedo of the library × (1 + margin).
    library_albedo_max : float
    worst : tuple of Offender
        The worst decodes of each kind (largest score first).
    criteria : PlausibilityCriteria
    energy_bound : bool
        Whether the decodes were judged with the energy bound applied.
    highlight_guard : bool
        Whether the decodes were judged after the highlight guard of edited records (§6 step 6).
    """

    materials: tuple[str, ...]
    dims: tuple[int, ...]
    steps: tuple[float, ...]
    fractions: dict[str, np.ndarray]
    source_inverted: float
    albedo_limit: float
    library_albedo_max: float
    worst: tuple[Offender, ...]
    criteria: PlausibilityCriteria = field(default_factory=PlausibilityCriteria)
    energy_bound: bool = True
    highlight_guard: bool = False

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (dims 1-based, as on the command line)."""
        return {
            "materials": len(self.materials),
            "dims": [d + 1 for d in self.dims],
            "steps": list(self.steps),
            "fractions": {k: np.round(v, 6).tolist() for k, v in self.fractions.items()},
            "source_inverted": self.source_inverted,
            "albedo_limit": self.albedo_limit,
            "library_albedo_max": self.library_albedo_max,
            "energy_bound": self.energy_bound,
            "highlight_guard": self.highlight_guard,
            "criteria": {"inversion_tolerance": self.criteria.inversion_tolerance,
                         "energy_margin": self.criteria.energy_margin},
            "worst": [{"material": o.material, "dim": o.dim + 1, "step": o.step, "kind": o.kind, "score": o.score,
                       "where": list(o.where)} for o in self.worst],
        }

    def format_table(self) -> str:
        """Per-dimension table: for each kind, the fraction flagged at each step (Markdown)."""
        steps = " | ".join(f"{s:+g}σ" for s in self.steps)
        lines = [f"| dim | kind | {steps} |", "|---|---|" + "---:|" * len(self.steps)]
        for i, dim in enumerate(self.dims):
            for kind in (*KINDS, *SUMMARY_KINDS):
                cells = " | ".join(f"{v:.3f}" for v in self.fractions[kind][i])
                lines.append(f"| z{dim + 1} | {kind} | {cells} |")
        totals = ", ".join(f"{k} {float(self.fractions[k].mean()):.3f}" for k in (*KINDS, *SUMMARY_KINDS))
        lines.append("")
        lines.append(f"All {len(self.materials)} materials × {len(self.dims)} dims × {len(self.steps)} steps: {totals}")
        lines.append(f"μ decodes with an inverted cell already: {self.source_inverted:.3f}; albedo limit "
                     f"{self.albedo_limit:.3f} (library max {self.library_albedo_max:.3f}); decodes judged "
                     + ("with the energy bound (as edits decode)" if self.energy_bound else "raw (no energy bound)")
                     + ("; after the highlight guard (§6 step 6)" if self.highlight_guard else ""))
        return "\n".join(lines)


def bounded(mapped: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Decodes (..., 63, 90, 90) with the energy bound applied, as edits decode (spec §6.3).

    Returns
    -------
    scaled : ndarray, same shape
        The kept slices of each bounded decode (exact at the kept φd bins).
    albedo : ndarray of float64, shape (...)
        Each bounded decode's largest directional albedo: ``s · max a`` of the raw decode, s its factor.
    """
    flat = np.asarray(mapped).reshape(-1, *NETWORK_INPUT_SHAPE)
    largest = directional_albedo_mapped(flat).max(axis=(-2, -1))
    scales = bound_scales(largest)
    out = flat.copy()  # decodes within the bound stay as they are (non-finite values too, for ``invalid``)
    for i in np.flatnonzero(scales < 1.0):
        out[i] = scale_mapped(flat[i], float(scales[i]))
    lead = np.shape(mapped)[:-3]
    return out.reshape(np.shape(mapped)), (largest * scales).reshape(lead)


def _wide_inversions(source: np.ndarray, mapped: np.ndarray) -> np.ndarray:
    """Per decode (lead shape of ``mapped``), how many columns :func:`inverted_highlights` flags, judged on the
    tables at the kept φd bins (exactly the decoded slices, unmapped)."""
    from brdfcodec.representation.network_io import table_from_mapped

    src = table_from_mapped(source, phi_d_bins=KEPT_PHI_D_SLICES)
    lead = mapped.shape[:-3]
    flat = mapped.reshape(-1, *NETWORK_INPUT_SHAPE)
    counts = np.zeros(len(flat), dtype=np.int64)
    with np.errstate(invalid="ignore", over="ignore"):
        for start in range(0, len(flat), 8):  # 8 tables of the kept bins at a time (16 MB)
            tables = table_from_mapped(flat[start : start + 8], phi_d_bins=KEPT_PHI_D_SLICES)
            counts[start : start + 8] = inverted_highlights(src, tables).reshape(len(tables), -1).sum(axis=-1)
    return counts.reshape(lead)


def _judge(
    source: np.ndarray, source_inv: np.ndarray, source_pits: np.ndarray, mapped: np.ndarray, limit: float, tol: float,
    directional: np.ndarray | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], np.ndarray]:
    """Flags and scores of each kind for edited decodes ``mapped`` (..., 63, 90, 90) of one source.

    ``directional``: each decode's largest directional albedo when known (a bounded decode's, from
    :func:`bounded`); computed from ``mapped`` otherwise.
    """
    lead = mapped.shape[:-3]
    bad = _invalid_counts(mapped.reshape(-1, *NETWORK_INPUT_SHAPE)).reshape(lead)
    new_inv = inverted_cells(mapped, tol) & ~source_inv
    depth = pit_depth(mapped)
    with np.errstate(invalid="ignore"):
        depth = np.where((depth > tol) & ~source_pits, depth, -np.inf)  # new pits only, measured once
    deficit = np.where(new_inv, specular_deficit(mapped), -np.inf)
    holes = new_holes(source, mapped).reshape(*lead, -1).sum(axis=-1)
    wide = _wide_inversions(source, mapped)
    albedo = white_sky_albedo(mapped).max(axis=-1)
    if directional is None:
        directional = directional_albedo_mapped(mapped.reshape(-1, *NETWORK_INPUT_SHAPE)).max(axis=(-2, -1))
        directional = directional.reshape(lead)
    flags = {
        "invalid": bad > 0,
        "inverted": new_inv.reshape(*lead, -1).any(axis=-1),
        "inverted_wide": wide > 0,
        "energetic": albedo > limit,
        "unphysical": directional > 1 + UNPHYSICAL_TOLERANCE,
        "holes": holes > 0,
        "pits": np.isfinite(depth).reshape(*lead, -1).any(axis=-1),
    }
    scores = {"invalid": bad, "inverted": deficit.reshape(*lead, -1).max(axis=-1), "inverted_wide": wide,
              "energetic": albedo,
              "unphysical": directional, "holes": holes, "pits": depth.reshape(*lead, -1).max(axis=-1)}
    return flags, scores, deficit


def plausible_range(
    decoder: Any,
    record: Any,
    dim: int,
    *,
    steps: Sequence[float] = DEFAULT_STEPS,
    albedo_limit: float | None = None,
    criteria: PlausibilityCriteria | None = None,
    energy_bound: bool = True,
    highlight_guard: bool = False,
) -> tuple[float, float]:
    """How far a traversal of ``record`` along ``dim`` stays plausible, on each side.

    Parameters
    ----------
    decoder : BrdfDecoder
    record : LatentRecord
    dim : int
        Latent dimension (0-based).
    steps : sequence of float, default ``(-3, -2, -1, 1, 2, 3)``
        Offsets tried, prior σ units.
    albedo_limit : float, optional
        Energy limit (:attr:`PlausibilityReport.albedo_limit`); without it energy is not checked.
    criteria : PlausibilityCriteria, optional
    energy_bound : bool, default True
        Judge the decodes with the energy bound applied, as edits decode.
    highlight_guard : bool, default False
        Judge the decodes after the highlight guard of edited records (``spec/bvae-format.md`` §6 step 6).

    Returns
    -------
    (low, high) : tuple of float
        The most negative and most positive offsets reached before the first
        implausible decode on that side (0 when the first step already is);
        an editor can keep traversals within them.
    """
    from brdfcodec.edit.latent_edits import require_latent, traverse

    require_latent(record)  # a record without a latent (format 2.1) has nothing to traverse
    tol = (criteria or PlausibilityCriteria()).inversion_tolerance
    steps = tuple(sorted(float(s) for s in steps if s != 0))
    source = decoder.decode_mapped(np.asarray(record.mu, dtype=np.float32)[None])
    codes = np.stack([np.asarray(e.mu, dtype=np.float32) for e in traverse(record, dim, steps)])
    mapped, directional = decoder.decode_mapped(codes), None
    if highlight_guard:
        mapped = guard_highlight(mapped)
    if energy_bound:
        mapped, directional = bounded(mapped)
    flags, _, _ = _judge(source[0], inverted_cells(source[0], tol), pit_cells(source[0], tol), mapped,
                         np.inf if albedo_limit is None else albedo_limit, tol, directional)
    bad = np.logical_or.reduce(list(flags.values()))
    low = high = 0.0
    for step, implausible in sorted(((s, b) for s, b in zip(steps, bad, strict=True) if s > 0)):
        if implausible:
            break
        high = step
    for step, implausible in sorted(((s, b) for s, b in zip(steps, bad, strict=True) if s < 0), reverse=True):
        if implausible:
            break
        low = step
    return low, high


def measure_plausibility(
    decoder: Any,
    records: Sequence[Any],
    *,
    dims: Sequence[int] | None = None,
    steps: Sequence[float] = DEFAULT_STEPS,
    criteria: PlausibilityCriteria | None = None,
    reference: Sequence[Any] | None = None,
    batch_size: int = 16,
    n_worst: int = 5,
    energy_bound: bool = True,
    highlight_guard: bool = False,
) -> PlausibilityReport:
    """Traverse every record along every dimension and count implausible decodes.

    Parameters
    ----------
    decoder : BrdfDecoder
        The decoder the records were made with.
    records : sequence of LatentRecord
        The library (their μ are the sources; grafted values are not traversed).
    dims : sequence of int, optional
        Latent dimensions (0-based); all by default.
    steps : sequence of float, default ``(-3, -2, -1, 1, 2, 3)``
        Offsets in prior σ units (:func:`brdfcodec.edit.latent_edits.traverse`).
    criteria : PlausibilityCriteria, optional
    reference : sequence of LatentRecord, optional
        The materials whose μ decodes set the energy limit (default: ``records``;
        pass the whole library when traversing a part of it).
    batch_size : int, default 16
        Codes per network call.
    n_worst : int, default 5
        Offenders kept per kind.
    energy_bound : bool, default True
        Judge the traversal decodes with the energy bound applied (``spec/bvae-format.md`` §6.3), as
        :func:`~brdfcodec.edit.latent_edits.traverse`'s records decode; False judges the raw decodes.
    highlight_guard : bool, default False
        Judge the traversal decodes after the highlight guard (``spec/bvae-format.md`` §6 step 6), as edited
        records decode; False judges the network's decodes (what a training objective has to fix).

    Returns
    -------
    PlausibilityReport
    """
    from brdfcodec.edit.latent_edits import require_latent, traverse

    criteria = criteria or PlausibilityCriteria()
    if not records:
        raise ValueError("no records to traverse")
    for record in [*records, *(reference or ())]:
        require_latent(record)  # records without a latent (format 2.1) have nothing to traverse
    dims = tuple(range(decoder.latent_dim)) if dims is None else tuple(int(d) for d in dims)
    if any(not 0 <= d < decoder.latent_dim for d in dims):
        raise ValueError(f"dims must lie in [0, {decoder.latent_dim}), got {list(dims)}")
    steps = tuple(float(s) for s in steps)
    if not steps or not all(np.isfinite(steps)):
        raise ValueError(f"steps must be a non-empty sequence of finite offsets, got {list(steps)}")
    tol = criteria.inversion_tolerance
    names = tuple(r.name for r in records)
    mus = np.stack([np.asarray(r.mu, dtype=np.float32) for r in records])
    sources = decoder.decode_mapped(mus, batch_size=batch_size)
    source_inv = inverted_cells(sources, tol)
    source_pits = pit_cells(sources, tol)
    if reference is None:
        library_max = float(white_sky_albedo(sources).max())
    else:
        ref_codes = np.stack([np.asarray(r.mu, dtype=np.float32) for r in reference])
        library_max = float(white_sky_albedo(decoder.decode_mapped(ref_codes, batch_size=batch_size)).max())
    limit = library_max * (1 + criteria.energy_margin)

    shape = (len(dims), len(steps))
    counts = {kind: np.zeros(shape) for kind in (*KINDS, *SUMMARY_KINDS)}
    offenders: dict[str, list[Offender]] = {kind: [] for kind in KINDS}
    for m, record in enumerate(records):
        edits = [e for d in dims for e in traverse(record, d, steps)]
        codes = np.stack([np.asarray(e.mu, dtype=np.float32) for e in edits])
        mapped = decoder.decode_mapped(codes, batch_size=batch_size).reshape(*shape, *NETWORK_INPUT_SHAPE)
        directional = None
        if highlight_guard:
            mapped = guard_highlight(mapped)
        if energy_bound:
            mapped, directional = bounded(mapped)
        flags, scores, deficit = _judge(sources[m], source_inv[m], source_pits[m], mapped, limit, tol, directional)
        for kind, flag in flags.items():
            counts[kind] += flag
            for i, j in zip(*np.nonzero(flag), strict=True):
                where: tuple[int, ...] = ()
                if kind == "inverted":
                    c, s, t = np.unravel_index(int(np.argmax(deficit[i, j])), deficit.shape[-3:])
                    where = (int(c), int(KEPT_PHI_D_SLICES[s]), int(t))
                offenders[kind].append(Offender(record.name, dims[i], steps[j], kind, float(scores[kind][i, j]),
                                                where))
        counts["highlight"] += flags["inverted"] | flags["holes"]
        counts["any"] += np.logical_or.reduce(list(flags.values()))
    worst = tuple(o for kind in KINDS for o in sorted(offenders[kind], key=lambda o: -o.score)[:n_worst])
    fractions = {kind: c / len(records) for kind, c in counts.items()}
    return PlausibilityReport(
        materials=names, dims=dims, steps=steps, fractions=fractions,
        source_inverted=float(source_inv.reshape(len(records), -1).any(axis=1).mean()),
        albedo_limit=limit, library_albedo_max=library_max, worst=worst, criteria=criteria,
        energy_bound=energy_bound, highlight_guard=highlight_guard,
    )
