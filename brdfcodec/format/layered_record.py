"""Layered records: the β-VAE latent (the base) plus enhancement layers (``spec/bvae-format.md`` §4.4).

A :class:`LayeredRecord` is a :class:`~brdfcodec.format.records.LatentRecord`
(so everything that reads a base latent — edits, parameters, the decoder's
base path — works on it unchanged) that also carries a
:class:`~brdfcodec.layers.detail.DetailLayer`. This module holds the
format's view of the layers: the index-entry object, the payload bytes, and
their validation when a file is read. It does not import torch.

A *basis-only* record (format 2.1, ``layers.mu = "none"``; :meth:`LayeredRecord.without_latent`) stores no
latent at all: its base is the decoder's linear-path mean, and its basis layer (and detail layer, if any) code the
rest. Its ``has_latent`` is False and its ``mu`` and ``sigma`` are NaN (so that code which would decode or edit a
latent it does not have fails loudly instead of using a made-up code); edits refuse it
(:class:`~brdfcodec.errors.NoLatentError`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.format.records import LatentRecord
from brdfcodec.io.hashing import is_reference_hex
from brdfcodec.layers.basis import (
    FIXED_MU_STEP,
    MAX_BASIS_COUNT,
    STEP_BYTES,
    BasisLayer,
    basis_layer_from_bytes,
    dequantise_int8,
    int8_from_step_bytes,
    int8_on_fixed_grid,
    int8_step_bytes,
    int8_with_step,
)
from brdfcodec.layers.coded_basis import MAX_CODED_BYTES, MAX_MAGNITUDE, MAX_MU_STEP_LOG2
from brdfcodec.layers.detail import _DTYPES, DETAIL_TRANSFORM, MAX_STEP, MIN_STEP, DetailLayer, check_detail_frame
from brdfcodec.layers.packed import MAX_TOP_WIDTH, packed_bytes, packed_widths

__all__ = [
    "LAYERED_KIND",
    "MU_CODED",
    "MU_INT8",
    "MU_INT8_FIXED",
    "MU_NONE",
    "SIGMA_LOG2_U8",
    "SIGMA_LOG2_U8_SHARED",
    "SIGMA_NONE",
    "LayeredRecord",
    "compact_mu_code",
    "compact_mu_values",
    "latent_values_stored",
    "layered_from_payload",
    "layers_entry",
    "layers_length",
    "quantise_sigma",
    "sigma_from_codes",
]

#: Record kind of a layered record in the index (``kind`` field).
LAYERED_KIND = "layered"
#: Largest detail layer a record may declare, in bytes (the raw float32 kept slices are 2 MB).
MAX_DETAIL_BYTES = 64 << 20
#: ``layers.sigma`` of a record that stores σ as one byte per dimension: σ = 2^(q/16 − 12), q in 0…255.
SIGMA_LOG2_U8 = "log2-u8"
#: ``layers.sigma`` of a record that stores one byte for all dimensions (the same code, ``"log2-u8"``'s scale).
SIGMA_LOG2_U8_SHARED = "log2-u8-shared"
#: ``layers.mu`` of a record that stores μ as a float16 step s and D int8 values q: μ = s · q (since 1.4).
MU_INT8 = "int8"
#: ``layers.mu`` of a record that stores μ as D int8 values q on the fixed grid: μ = q / 32 (since 1.5).
MU_INT8_FIXED = "int8-fixed"
#: ``layers.mu`` of a record that entropy-codes μ on the grid 2^−g in its coded basis layer's stream (since 2.5).
MU_CODED = "coded"
#: ``layers.mu`` (and ``layers.sigma``, :data:`SIGMA_NONE`) of a basis-only record, which stores no latent (since 2.1).
MU_NONE = "none"
#: ``layers.sigma`` of a basis-only record: no σ (only with ``layers.mu = "none"``).
SIGMA_NONE = "none"
_MU_MODES = (MU_INT8, MU_INT8_FIXED)
_SIGMA_LOG2_MIN, _SIGMA_STEPS_PER_OCTAVE = -12.0, 16.0
_SIGMA_MODES = (SIGMA_LOG2_U8, SIGMA_LOG2_U8_SHARED)


def quantise_sigma(sigma: np.ndarray) -> np.ndarray:
    """One byte per posterior width: ``round(16 · (log2 σ + 12))`` clipped to 0…255 (σ within 2.2 %)."""
    log2 = np.log2(np.maximum(np.asarray(sigma, dtype=np.float64), 1e-30))
    return np.clip(np.rint((log2 - _SIGMA_LOG2_MIN) * _SIGMA_STEPS_PER_OCTAVE), 0, 255).astype(np.uint8)


def shared_sigma_code(sigma: np.ndarray) -> np.ndarray:
    """The one byte of a shared σ: the code of the geometric mean of the widths (:func:`quantise_sigma`)."""
    log2 = np.log2(np.maximum(np.asarray(sigma, dtype=np.float64), 1e-30))
    return quantise_sigma(np.exp2(np.array([log2.mean()])))


def sigma_from_codes(codes: np.ndarray) -> np.ndarray:
    """Inverse of :func:`quantise_sigma`: σ = 2^(q/16 − 12), float32 (exact for every code)."""
    return np.exp2(np.asarray(codes, dtype=np.float64) / _SIGMA_STEPS_PER_OCTAVE + _SIGMA_LOG2_MIN).astype(np.float32)


def compact_mu_code(mu: npt.ArrayLike, fixed_grid: bool, what: str = "mu") -> tuple[float, np.ndarray]:
    """A compact μ as stored: ``(step, q)``, μ ≈ step · q with q int8 — on the fixed grid (step 1/32,
    ``layers.mu = "int8-fixed"``) or with its own float16 step (``"int8"``)."""
    if fixed_grid:
        return FIXED_MU_STEP, int8_on_fixed_grid(mu, what)
    return int8_with_step(mu, what)


def compact_mu_values(mu: npt.ArrayLike, fixed_grid: bool, what: str = "mu") -> npt.NDArray[np.float32]:
    """The float32 values a compact μ decodes to (what an encoder fits the layers to)."""
    return dequantise_int8(*compact_mu_code(mu, fixed_grid, what))


@dataclass(frozen=True)
class LayeredRecord(LatentRecord):
    """A base latent record plus enhancement layers: a basis layer, a detail layer, or both; or, without a latent
    (``has_latent=False``, format 2.1), a basis layer (and a detail layer) on the decoder's linear-path mean.

    Attributes
    ----------
    name, mu, sigma, meta
        As in :class:`~brdfcodec.format.records.LatentRecord`: ``mu`` is the
        base code (refined at encode time, see ``spec/bvae-format.md`` §4.4),
        ``sigma`` the encoder's posterior width.
    detail : DetailLayer or None
        The residual of the kept slices left by decoding ``mu`` and the basis layer.
    basis : BasisLayer or None
        Coefficients on the model's shared basis.
    compact_sigma : bool
        Store σ as one byte per dimension (``layers.sigma = "log2-u8"``, within 2.2 %) instead of in the
        file's latent dtype. ``sigma`` then holds the stored (quantised) widths.
    shared_sigma : bool
        Store one byte for all of σ (``layers.sigma = "log2-u8-shared"``): the geometric mean of the widths,
        which ``sigma`` then holds in every dimension. Excludes ``compact_sigma``.
    compact_mu : bool
        Store μ as a float16 step and one signed byte per dimension (``layers.mu = "int8"``: 2 + D bytes,
        each value within half a step, max |μ| / 254) instead of in the file's latent dtype. ``mu`` then
        holds the stored (quantised) code.
    fixed_mu_grid : bool
        With ``compact_mu``: store μ as one signed byte per dimension on the fixed grid μ = q / 32
        (``layers.mu = "int8-fixed"``: D bytes, no step; values past ±3.97 are stored as the grid's end).
    store_sigma : bool
        False: σ is not stored (``layers.sigma = "none"`` with a latent, format 2.2); ``sigma`` then holds 1 in
        every dimension, the prior's width: nothing is claimed about the posterior. Such a record may hold no
        layer at all: it is then the base alone, μ in the form's storage (``spec/bvae-format.md`` §4.4).
    stored_mu : (float, ndarray of int8) or None
        With ``compact_mu``: the code as stored, ``(t, q)`` with μ = t · q (t = 1/32 on the fixed grid), which
        ``mu`` then holds exactly (``spec/bvae-format.md`` §4.5). A reader passes the stored code, so a record is
        never re-quantised when it is read (q = −128 and any positive finite binary16 step included); None (a
        writer's record): the code is made from ``mu`` (:func:`compact_mu_code`), and ``mu`` holds its values. A
        code that does not give ``mu`` (a record copied with a new ``mu``) is made anew from ``mu`` too.
    coded_mu : int, default 0
        g > 0: μ is entropy-coded on the grid μ = q · 2^−g (g = 1 … 5) ahead of the coefficients in the record's
        coded basis layer (``layers.mu = "coded"``, format 2.5, ``spec/bvae-format.md`` §4.9): about 6 bytes for
        D = 8 at g = 4, against 8 on the fixed grid. Needs an entropy-coded basis layer; ``mu`` then holds the
        values on the grid (rounded to nearest), and the layer's ``coded_mu`` is made from them. 0: not coded.
    has_latent : bool
        False: a basis-only record (format 2.1, ``layers.mu = layers.sigma = "none"``; make one with
        :meth:`without_latent`). It stores neither μ nor σ; its base is the decoder's linear-path mean
        (``spec/bvae-format.md`` §4.6). It needs a basis layer whose base is not projected; ``mu`` and ``sigma``
        then hold NaN (only their length, the file's latent dimension, means something) and the compact forms
        are off.
    """

    detail: DetailLayer | None = None
    kind: Literal["layered"] = field(default="layered", init=False)  # type: ignore[assignment]
    basis: BasisLayer | None = None
    compact_sigma: bool = False
    shared_sigma: bool = False
    compact_mu: bool = False
    fixed_mu_grid: bool = False
    has_latent: bool = True
    store_sigma: bool = True
    stored_mu: tuple[float, np.ndarray] | None = field(default=None, compare=False, repr=False)
    coded_mu: int = 0

    @classmethod
    def without_latent(
        cls, name: str, latent_dim: int, basis: BasisLayer, *, detail: DetailLayer | None = None,
        meta: Mapping[str, Any] | None = None,
    ) -> LayeredRecord:
        """A basis-only record (format 2.1): no μ, no σ; the base is the decoder's linear-path mean.

        Parameters
        ----------
        name : str
        latent_dim : int
            The latent dimension of the file's decoder (every record of a file has it).
        basis : BasisLayer
            The coefficients (its ``project`` must be 0).
        detail : DetailLayer, optional
        meta : mapping, optional
        """
        return cls(name, np.zeros(latent_dim, dtype=np.float32), np.ones(latent_dim, dtype=np.float32),
                   {} if meta is None else meta, detail=detail, basis=basis, has_latent=False)

    def __post_init__(self) -> None:
        if not self.has_latent:  # placeholders that pass the latent record's checks, replaced by NaN below
            size = int(np.asarray(self.mu).size)
            self._hold("mu", np.zeros(size))
            self._hold("sigma", np.ones(size))
        super().__post_init__()
        if not self.has_latent:
            if self.basis is None:
                raise ValueError(f"{self.name}: a record without a latent needs a basis layer")
            if not isinstance(self.basis, BasisLayer):
                raise ValueError(f"{self.name}: basis must be a BasisLayer, got {type(self.basis).__name__}")
            if self.basis.project:
                raise ValueError(f"{self.name}: a record without a latent has no base decode to project "
                                 f"(basis project must be 0, got {self.basis.project})")
            if self.compact_sigma or self.shared_sigma or self.compact_mu or self.fixed_mu_grid:
                raise ValueError(f"{self.name}: a record without a latent stores no mu or sigma, compact or not")
            self._hold("mu", np.full(self.mu.size, np.nan))
            self._hold("sigma", np.full(self.sigma.size, np.nan))
        if not self.store_sigma and self.has_latent:
            if self.compact_sigma or self.shared_sigma:
                raise ValueError(f"{self.name}: sigma is either not stored or stored compactly, not both")
            self._hold("sigma", np.ones(self.sigma.size))
        if self.detail is None and self.basis is None and self.store_sigma:
            raise ValueError(f"{self.name}: a layered record needs a basis layer, a detail layer or both (or, "
                             "without a stored sigma, none: the base alone)")
        if self.detail is not None and not isinstance(self.detail, DetailLayer):
            raise ValueError(f"{self.name}: detail must be a DetailLayer, got {type(self.detail).__name__}")
        if self.basis is not None and not isinstance(self.basis, BasisLayer):
            raise ValueError(f"{self.name}: basis must be a BasisLayer, got {type(self.basis).__name__}")
        if self.compact_sigma and self.shared_sigma:
            raise ValueError(f"{self.name}: sigma is stored either per dimension or shared, not both")
        if self.fixed_mu_grid and not self.compact_mu:
            raise ValueError(f"{self.name}: the fixed mu grid is a compact mu (compact_mu=True)")
        # What is stored is what the record holds, so writing and reading agree.
        if self.compact_sigma:
            self._hold("sigma", sigma_from_codes(quantise_sigma(self.sigma)))
        if self.shared_sigma:
            self._hold("sigma", np.repeat(sigma_from_codes(shared_sigma_code(self.sigma)), len(self.mu)))
        code = self._stored_code() if self.compact_mu else None
        object.__setattr__(self, "stored_mu", code)
        if code is not None:
            self._hold("mu", dequantise_int8(*code))
        if self.coded_mu:
            self._code_mu_in_layer()
        elif self.basis is not None and self.basis.coded_mu is not None:
            object.__setattr__(self, "basis", dataclasses.replace(self.basis, coded_mu=None))

    def _code_mu_in_layer(self) -> None:
        """A coded μ (format 2.5): ``mu`` rounded to the grid 2^−g, and its integers set in the coded layer."""
        g = self.coded_mu
        if isinstance(g, bool) or not isinstance(g, int | np.integer) or not 1 <= g <= MAX_MU_STEP_LOG2:
            raise ValueError(f"{self.name}: a coded mu's grid exponent must be an integer 1 to {MAX_MU_STEP_LOG2}, "
                             f"got {g!r}")
        if not self.has_latent or self.compact_mu:
            raise ValueError(f"{self.name}: a coded mu is a record's latent, stored neither compact nor absent")
        if self.basis is None or self.basis.prior is None:
            raise ValueError(f"{self.name}: a coded mu rides in an entropy-coded basis layer, which it lacks")
        scaled = np.rint(np.asarray(self.mu, dtype=np.float64) * float(1 << g))
        if not np.isfinite(scaled).all() or np.abs(scaled).max(initial=0.0) > MAX_MAGNITUDE:
            raise ValueError(f"{self.name}: mu is past a coded mu's range (±{MAX_MAGNITUDE} steps of 2^-{g})")
        q = scaled.astype(np.int64)
        q.setflags(write=False)
        self._hold("mu", q / float(1 << g))  # exact in float32 (|q| < 2^22)
        given = self.basis.coded_mu
        if given is None or given[0] != g or not np.array_equal(given[1], q):
            object.__setattr__(self, "basis", dataclasses.replace(self.basis, coded_mu=(int(g), q)))

    def _stored_code(self) -> tuple[float, np.ndarray]:
        """The compact μ's ``(t, q)``: the one given when it is a code of this form that gives ``mu`` exactly
        (read from a file), else the code :func:`compact_mu_code` makes from ``mu`` (a writer's record)."""
        given = self.stored_mu
        if given is not None:
            step, q = float(given[0]), np.asarray(given[1])
            valid_step = step == FIXED_MU_STEP if self.fixed_mu_grid else (
                np.isfinite(step) and step > 0 and float(np.float16(step)) == step)
            if (valid_step and q.shape == np.shape(self.mu) and q.dtype == np.int8
                    and np.array_equal(dequantise_int8(step, q), np.asarray(self.mu, dtype=np.float32))):
                q = q.copy()
                q.setflags(write=False)
                return step, q
        return compact_mu_code(self.mu, self.fixed_mu_grid, f"{self.name}: mu")

    def _hold(self, field_name: str, values: np.ndarray) -> None:
        """Replace ``mu`` or ``sigma`` by the values stored (float32, read-only like the base record's)."""
        array = np.asarray(values, dtype=np.float32)
        array.setflags(write=False)
        object.__setattr__(self, field_name, array)

    def _mu_code(self) -> tuple[float, np.ndarray]:
        assert self.stored_mu is not None  # set by __post_init__ for every compact μ
        return self.stored_mu

    @property
    def sigma_bytes_stored(self) -> bool:
        """Whether σ is stored as bytes after the latent values (per dimension or shared) rather than among them."""
        return self.compact_sigma or self.shared_sigma

    @property
    def sigma_in_values(self) -> bool:
        """Whether σ is among the values stored in the latent dtype (not compact, not omitted)."""
        return self.has_latent and self.store_sigma and not self.sigma_bytes_stored

    @property
    def mu_storage(self) -> str | None:
        """How μ is stored (``layers.mu``): None in the file's latent dtype, :data:`MU_INT8`, :data:`MU_INT8_FIXED`,
        or :data:`MU_NONE` (no latent)."""
        if not self.has_latent:
            return MU_NONE
        if self.coded_mu:
            return MU_CODED
        if self.compact_mu:
            return MU_INT8_FIXED if self.fixed_mu_grid else MU_INT8
        return None

    def payload_values(self) -> np.ndarray:
        """Values stored in the latent dtype: ``mu`` unless it is compact, ``sigma`` unless it is stored as bytes
        (none for a record without a latent)."""
        if not self.has_latent:
            return np.zeros(0, dtype=np.float32)
        in_values = not (self.compact_mu or self.coded_mu)
        parts = ([self.mu] if in_values else []) + ([self.sigma] if self.sigma_in_values else [])
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.float32)

    def base(self) -> LatentRecord:
        """The base alone: a plain latent record with the same μ, σ and meta (what a graft is made of; other
        edits keep the layers, ``spec/bvae-format.md`` §4.4).

        Raises
        ------
        NoLatentError
            A basis-only record has no latent base.
        """
        if not self.has_latent:
            from brdfcodec.errors import NoLatentError

            raise NoLatentError(self.name)
        return LatentRecord(self.name, self.mu, self.sigma, self.meta)

    @classmethod
    def code_only(cls, record: LatentRecord) -> LayeredRecord:
        """A latent record without its σ (format 2.2): μ in the file's latent dtype and no layer."""
        return cls(record.name, record.mu, record.sigma, record.meta, store_sigma=False)

    @property
    def has_layers(self) -> bool:
        """Whether the record holds a basis or a detail layer (a σ-less base alone holds none)."""
        return self.basis is not None or self.detail is not None

    def layer_bytes(self) -> bytes:
        """The bytes that follow the latent values: compact μ, compact σ, the basis layer's, then the detail
        layer's."""
        mu = b""
        if self.compact_mu:
            mu = self._mu_code()[1].tobytes() if self.fixed_mu_grid else int8_step_bytes(*self._mu_code())
        sigma = quantise_sigma(self.sigma).tobytes() if self.compact_sigma else b""
        if self.shared_sigma:
            sigma = shared_sigma_code(self.sigma).tobytes()
        return (mu + sigma + (b"" if self.basis is None else self.basis.data)
                + (b"" if self.detail is None else self.detail.data))


def layers_entry(record: LayeredRecord) -> dict[str, Any]:
    """The ``layers`` object of a layered record's index entry."""
    entry: dict[str, Any] = {}
    if not record.has_latent:
        entry["mu"], entry["sigma"] = MU_NONE, SIGMA_NONE
    elif not record.store_sigma:
        entry["sigma"] = SIGMA_NONE
    if record.compact_mu:
        entry["mu"] = MU_INT8_FIXED if record.fixed_mu_grid else MU_INT8
    if record.coded_mu:
        entry["mu"] = MU_CODED
    if record.compact_sigma:
        entry["sigma"] = SIGMA_LOG2_U8
    if record.shared_sigma:
        entry["sigma"] = SIGMA_LOG2_U8_SHARED
    if record.basis is not None:
        entry["basis"] = record.basis.entry()
    if record.detail is not None:
        entry["detail"] = record.detail.entry()
    return entry


def latent_values_stored(layers: Mapping[str, Any], latent_dim: int) -> int:
    """Values a layered record stores in the latent dtype (its ``layers`` already validated): 0, D or 2·D (0 for a
    record without a latent, whose ``mu`` and ``sigma`` are ``"none"``)."""
    return (0 if "mu" in layers else latent_dim) + (0 if "sigma" in layers else latent_dim)


def layers_length(layers: object, where: str, latent_dim: int = 0) -> int:
    """Validate an index entry's ``layers`` object and return the bytes its layers (and compact σ) take.

    Raises
    ------
    ValueError
        Missing or malformed fields (the message says which); the caller wraps it in a format error.
    UnsupportedLayerError
        A layer or transform this reader does not know.
    """
    if not isinstance(layers, Mapping):
        raise ValueError(f"{where} field 'layers' is not a JSON object")
    unknown = sorted(set(layers) - {"basis", "detail", "sigma", "mu"})
    if unknown:
        raise UnsupportedLayerError(f"{where} has layers {unknown}, unknown to this reader; upgrade brdfcodec")
    if "basis" not in layers and "detail" not in layers and not (
        layers.get("sigma") == SIGMA_NONE and layers.get("mu") != MU_NONE
    ):
        raise ValueError(f"{where} layers hold neither 'basis' nor 'detail' (only a record without a stored sigma "
                         "may be its base alone)")
    length = 0
    for key in ("mu", "sigma"):
        if key in layers and not isinstance(layers[key], str):
            raise ValueError(f"{where} layers.{key} is not a string")
    no_latent = layers.get("mu") == MU_NONE
    if no_latent and layers.get("sigma") != SIGMA_NONE:
        raise ValueError(f"{where} stores no mu but a sigma: a record without a latent stores neither")
    no_sigma = layers.get("sigma") == SIGMA_NONE  # with a latent: σ not stored (2.2)
    if no_latent:
        if "basis" not in layers:
            raise ValueError(f"{where} stores no latent and no basis layer (a record without a latent needs one)")
        if isinstance(layers["basis"], Mapping) and layers["basis"].get("project", 0) != 0:
            raise ValueError(f"{where} stores no latent but projects its base on the basis (project must be 0)")
    elif layers.get("mu") == MU_CODED:  # format 2.5: in the coded basis layer's stream, which it needs
        basis = layers.get("basis")
        if not isinstance(basis, Mapping) or "prior" not in basis or "mu_step" not in basis:
            raise ValueError(f"{where} codes mu in a basis layer that is not entropy-coded (or names no mu step)")
        g = basis["mu_step"]
        if not isinstance(g, int) or isinstance(g, bool) or not 1 <= g <= MAX_MU_STEP_LOG2:
            raise ValueError(f"{where} coded mu step {g!r} is not an integer in [1, {MAX_MU_STEP_LOG2}]")
    elif "mu" in layers:
        if layers["mu"] not in _MU_MODES:
            raise UnsupportedLayerError(
                f"{where} stores mu as {layers['mu']!r}, unknown to this reader ({' or '.join(_MU_MODES)}); "
                "upgrade brdfcodec"
            )
        length += latent_dim + (STEP_BYTES if layers["mu"] == MU_INT8 else 0)
    if "sigma" in layers and not no_latent and not no_sigma:
        if layers["sigma"] not in _SIGMA_MODES:
            raise UnsupportedLayerError(
                f"{where} stores sigma as {layers['sigma']!r}, unknown to this reader "
                f"({' or '.join(_SIGMA_MODES)}); upgrade brdfcodec"
            )
        length += 1 if layers["sigma"] == SIGMA_LOG2_U8_SHARED else latent_dim
    if "basis" in layers:
        length += _basis_length(layers["basis"], where)
    if "detail" in layers:
        length += _detail_length(layers["detail"], where)
    return length


def _basis_length(basis: object, where: str) -> int:
    if not isinstance(basis, Mapping):
        raise ValueError(f"{where} layers.basis is not a JSON object")
    unknown = sorted(set(basis) - {"sha256", "count", "first", "project", "top", "prior", "length", "mu_step"})
    if unknown:
        raise UnsupportedLayerError(
            f"{where} basis layer has fields {unknown}, unknown to this reader; upgrade brdfcodec"
        )
    sha, count, first = basis.get("sha256"), basis.get("count"), basis.get("first", 0)
    project = basis.get("project", 1)  # absent: no projection
    if not is_reference_hex(sha):
        raise ValueError(f"{where} basis sha256 {sha!r} is not 64 lower-case hex digits (or a short reference's 16)")
    if not isinstance(count, int) or isinstance(count, bool) or not 1 <= count <= MAX_BASIS_COUNT:
        raise ValueError(f"{where} basis count {count!r} is not an integer in [1, {MAX_BASIS_COUNT}]")
    if not isinstance(first, int) or isinstance(first, bool) or not 0 <= first <= MAX_BASIS_COUNT - count:
        raise ValueError(
            f"{where} basis first {first!r} is not an integer in [0, {MAX_BASIS_COUNT} − count]"
        )
    if not isinstance(project, int) or isinstance(project, bool) or not 1 <= project <= MAX_BASIS_COUNT:
        raise ValueError(f"{where} basis project {project!r} is not an integer in [1, {MAX_BASIS_COUNT}]")
    if "mu_step" in basis and "prior" not in basis:
        raise ValueError(f"{where} basis layer carries a coded mu but is not entropy-coded")
    if "prior" in basis or "length" in basis:  # entropy-coded (format 2.4, spec §4.8)
        return _coded_length(basis, where)
    if "top" in basis:
        top = basis["top"]
        if not isinstance(top, int) or isinstance(top, bool) or not 1 <= top <= MAX_TOP_WIDTH:
            raise ValueError(f"{where} basis top width {top!r} is not an integer in [1, {MAX_TOP_WIDTH}]")
        if packed_widths(top, first, count)[-1] < 1:
            raise ValueError(f"{where} packs {count} basis coefficients from vector {first} with top width {top}, "
                             "more than it holds (every field needs at least 1 bit)")
        return packed_bytes(top, first, count)
    return STEP_BYTES + count


def _coded_length(basis: Mapping[str, Any], where: str) -> int:
    """An entropy-coded basis layer's ``prior`` (two integers 0 … 255) and ``length`` (its bytes, step code
    included), checked; returns the length."""
    prior, length = basis.get("prior"), basis.get("length")
    if "top" in basis:
        raise ValueError(f"{where} basis layer is both packed and entropy-coded")
    if not isinstance(prior, list | tuple) or len(prior) != 2 or any(
            not isinstance(v, int) or isinstance(v, bool) or not 0 <= v <= 255 for v in prior):
        raise ValueError(f"{where} coded basis prior {prior!r} is not two integers in [0, 255]")
    if not isinstance(length, int) or isinstance(length, bool) or not 1 <= length <= MAX_CODED_BYTES:
        raise ValueError(f"{where} coded basis length {length!r} is not an integer in [1, {MAX_CODED_BYTES}]")
    return length


def _detail_length(detail: object, where: str) -> int:
    if not isinstance(detail, Mapping):
        raise ValueError(f"{where} layers.detail is not a JSON object")
    unknown = sorted(set(detail) - {"transform", "step", "dtype", "length"})
    if unknown:
        raise UnsupportedLayerError(
            f"{where} detail layer has fields {unknown}, unknown to this reader; upgrade brdfcodec"
        )
    transform = detail.get("transform")
    if not isinstance(transform, str):
        raise ValueError(f"{where} detail transform {transform!r} is not a string")
    if transform != DETAIL_TRANSFORM:
        raise UnsupportedLayerError(
            f"{where} detail transform {transform!r} is unknown to this reader ({DETAIL_TRANSFORM}); upgrade brdfcodec"
        )
    step, dtype, length = detail.get("step"), detail.get("dtype"), detail.get("length")
    if not isinstance(step, float | int) or isinstance(step, bool) or not MIN_STEP <= float(step) <= MAX_STEP:
        raise ValueError(f"{where} detail step {step!r} is not a number in [{MIN_STEP}, {MAX_STEP}]")
    if not isinstance(dtype, str):
        raise ValueError(f"{where} detail dtype {dtype!r} is not a string")
    if dtype not in _DTYPES:
        raise UnsupportedLayerError(
            f"{where} detail dtype {dtype!r} is unknown to this reader ({', '.join(sorted(_DTYPES))}); "
            "upgrade brdfcodec"
        )
    if not isinstance(length, int) or isinstance(length, bool) or not 1 <= length <= MAX_DETAIL_BYTES:
        raise ValueError(f"{where} detail length {length!r} is not an integer in [1, {MAX_DETAIL_BYTES}]")
    return length


class UnsupportedLayerError(ValueError):
    """A layer kind or transform that this reader does not implement (mapped to UnsupportedVersionError)."""


def layered_from_payload(
    name: str, values: np.ndarray, latent_dim: int, layers: Mapping[str, Any], tail: bytes, meta: Mapping[str, Any]
) -> LayeredRecord:
    """A layered record from its validated entry, the values stored in the latent dtype (μ unless compact,
    then σ unless stored as bytes: :func:`latent_values_stored` of them) and the payload bytes after them."""
    d = latent_dim
    if layers.get("mu") == MU_NONE:  # a basis-only record (format 2.1): the basis layer, then any detail layer
        size = _basis_length(layers["basis"], name)
        coefficients = basis_layer_from_bytes(layers["basis"], bytes(tail[:size]))
        residual = None
        if "detail" in layers:
            entry = layers["detail"]
            residual = DetailLayer(float(entry["step"]), str(entry["dtype"]), bytes(tail[size:]))
            check_detail_frame(residual.data, residual.dtype)  # decompressed whole at read, as below
        return LayeredRecord.without_latent(name, d, coefficients, detail=residual, meta=meta)
    coded_mu = layers.get("mu") == MU_CODED
    compact_mu = layers.get("mu") in _MU_MODES
    fixed_mu_grid = layers.get("mu") == MU_INT8_FIXED
    stored_mu = None  # a compact μ is μ = t·q exactly as stored (§4.5): the record keeps the code, never re-quantised
    if fixed_mu_grid:
        stored_mu = (FIXED_MU_STEP, np.frombuffer(tail[:d], dtype=np.int8).copy())
        tail = tail[d:]
    elif compact_mu:
        stored_mu = int8_from_step_bytes(tail[: STEP_BYTES + d], "compact mu step")
        tail = tail[STEP_BYTES + d :]
    elif not coded_mu:
        mu, values = values[:d], values[d:]
    if stored_mu is not None:
        mu = dequantise_int8(*stored_mu)
    compact = layers.get("sigma") == SIGMA_LOG2_U8
    shared = layers.get("sigma") == SIGMA_LOG2_U8_SHARED
    store_sigma = layers.get("sigma") != SIGMA_NONE
    if not store_sigma:
        sigma = np.ones(d, dtype=np.float32)
    elif compact:
        sigma = sigma_from_codes(np.frombuffer(tail[:d], dtype=np.uint8))
        tail = tail[d:]
    elif shared:
        sigma = np.repeat(sigma_from_codes(np.frombuffer(tail[:1], dtype=np.uint8)), d)
        tail = tail[1:]
    else:
        sigma = values[:d]
    flags: dict[str, Any] = {"compact_sigma": compact, "shared_sigma": shared, "compact_mu": compact_mu,
                             "fixed_mu_grid": fixed_mu_grid, "store_sigma": store_sigma, "stored_mu": stored_mu}
    basis = None
    if "basis" in layers:
        size = _basis_length(layers["basis"], name)
        basis = basis_layer_from_bytes(layers["basis"], bytes(tail[:size]), d)
        tail = tail[size:]
    if coded_mu:  # format 2.5: μ = q · 2^−g, its integers the first D of the coded layer's stream (§4.9)
        assert basis is not None and basis.coded_mu is not None
        g, q = basis.coded_mu
        mu, flags["coded_mu"] = (np.asarray(q, dtype=np.float64) / float(1 << g)).astype(np.float32), g
    if "detail" not in layers:
        return LayeredRecord(name, mu, sigma, meta, basis=basis, **flags)
    detail = layers["detail"]
    layer = DetailLayer(float(detail["step"]), str(detail["dtype"]), bytes(tail))
    check_detail_frame(layer.data, layer.dtype)  # decompressed whole at read: one frame, nothing after it (§4.4)
    return LayeredRecord(name, mu, sigma, meta, detail=layer, basis=basis, **flags)
