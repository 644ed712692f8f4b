"""The basis layer of a record: quantised coefficients on the shared basis, checked against it, and their bytes.

Part of :mod:`brdfcodec.layers.basis`, which gathers the names of its parts.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from brdfcodec.errors import BasisError, BasisMismatchError
from brdfcodec.io.hashing import is_reference_hex
from brdfcodec.layers.coded_basis import (
    CODED_HEADER_BYTES,
    MAX_CODED_BYTES,
    MAX_MAGNITUDE,
    choose_coding,
    coded_mu_codes,
    decode_integers,
    encode_integers,
    mu_stream_lead,
    prior_codes,
)
from brdfcodec.layers.packed import (
    MAX_TOP_WIDTH,
    PACKED_HEADER_BYTES,
    choose_packing,
    pack_fields,
    packed_bytes,
    packed_step,
    packed_step_code,
    packed_widths,
    unpack_fields,
)
from brdfcodec.layers.quantise import (
    MAX_BASIS_COUNT,
    STEP_BYTES,
    dequantise_int8,
    int8_from_step_bytes,
    int8_step_bytes,
    int8_with_step,
)
from brdfcodec.layers.shared_basis import SharedBasis, linear_path_entries

__all__ = [
    "BasisLayer",
    "basis_layer_from_bytes",
    "check_basis_layers",
    "check_records_without_latent",
    "coded_coefficients",
    "packed_coefficients",
    "quantise_coefficients",
]


@dataclass(frozen=True)
class BasisLayer:
    """A record's coefficients on its model's shared basis.

    Attributes
    ----------
    sha256 : str
        The shared basis' SHA-256 (64 lower-case hex digits), or its first 16 in a record read from a file with
        short references (format 2.6, ``spec/bvae-format.md`` §3.1).
    step : float
        Quantisation step s, mapped units: a positive, finite float16 value, or in a packed layer one of the
        steps 2^(e/16 − 8) (:func:`~brdfcodec.layers.packed.packed_step`).
    q : ndarray of int8 (int64 in a packed layer), shape (k,)
        Quantised coefficients; the coefficients are ``s · q``.
    first : int, default 0
        Index of the basis vector of the first coefficient: the layer codes
        ``Σᵢ s·qᵢ · b_(first+i)`` (format 1.3; 0 in older files). An encoder
        skips the leading vectors that its decoder's linear path already
        spans (:func:`basis_offset`).
    project : int, default 0
        P > 0: the base decode is projected on the basis' first P vectors
        around the decoder's linear-path mean before the layer is added
        (format 1.6, :meth:`SharedBasis.project`); 0: it is not.
    top : int, default 0
        T > 0: a packed layer (format 2.3, :mod:`brdfcodec.layers.packed`), coefficient i a field of
        T − round(log₂(first + i + 1)) bits; 0: int8 coefficients.
    prior : (int, int) or None, default None
        An entropy-coded layer (format 2.4, :mod:`brdfcodec.layers.coded_basis`): the form's Laplace prior
        (amplitude A, decay d, 0 … 255 each; vector n's spread 2^(A/16 − 4)·n^(−d/32) mapped units); the step
        is a packed step. None: not coded.
    coded_mu : (int, ndarray of int64) or None, default None
        A coded layer only: ``(g, q)``, a record's μ = q · 2^−g entropy-coded ahead of the coefficients in the
        layer's stream (format 2.5, ``spec/bvae-format.md`` §4.9); the layer's bytes and length include it. Set
        by :class:`~brdfcodec.format.layered_record.LayeredRecord` from its ``mu``. None: the stream holds the
        coefficients alone.
    """

    sha256: str
    step: float
    q: npt.NDArray[np.int8] | npt.NDArray[np.int64]
    first: int = 0
    project: int = 0
    top: int = 0
    prior: tuple[int, int] | None = None
    coded_mu: tuple[int, npt.NDArray[np.int64]] | None = None

    def __post_init__(self) -> None:
        if not is_reference_hex(self.sha256):
            raise ValueError(f"basis sha256 must be 64 lower-case hex digits (or a short reference's first 16), "
                             f"got {self.sha256!r}")
        q = np.asarray(self.q)
        if self.coded_mu is not None:
            self._check_coded_mu()
        if self.prior is not None:
            self._check_coded(q)
        elif self.top:
            self._check_packed(q)
        else:
            step = np.float16(self.step)
            if not (np.isfinite(step) and step > 0 and float(step) == float(self.step)):
                raise ValueError(f"basis step must be a positive finite float16 value, got {self.step!r}")
            if q.dtype != np.int8 or q.ndim != 1 or not 1 <= len(q) <= MAX_BASIS_COUNT:
                raise ValueError(f"basis coefficients must be 1 to {MAX_BASIS_COUNT} int8 values")
        if isinstance(self.first, bool) or not isinstance(self.first, int | np.integer) or not (
            0 <= self.first and self.first + len(q) <= MAX_BASIS_COUNT
        ):
            raise ValueError(f"basis first vector must be an integer with first + count ≤ {MAX_BASIS_COUNT}, "
                             f"got {self.first!r}")
        if isinstance(self.project, bool) or not isinstance(self.project, int | np.integer) or not (
            0 <= self.project <= MAX_BASIS_COUNT
        ):
            raise ValueError(f"basis projection must be an integer in [0, {MAX_BASIS_COUNT}], got {self.project!r}")

    def _check_coded(self, q: np.ndarray) -> None:
        """The coded layer's own rules: a prior of two bytes, a packed step, integers within the coder's range."""
        prior = self.prior
        if (not isinstance(prior, tuple) or len(prior) != 2 or any(
                isinstance(v, bool) or not isinstance(v, int | np.integer) or not 0 <= v <= 255 for v in prior)):
            raise ValueError(f"a coded basis layer's prior must be two integers in [0, 255], got {prior!r}")
        if self.top:
            raise ValueError("a basis layer is either packed or entropy-coded, not both")
        packed_step_code(self.step)
        if q.ndim != 1 or not np.issubdtype(q.dtype, np.integer) or not 1 <= len(q) <= MAX_BASIS_COUNT:
            raise ValueError(f"basis coefficients must be 1 to {MAX_BASIS_COUNT} integers")
        if int(np.abs(q.astype(np.int64)).max()) > MAX_MAGNITUDE:
            raise ValueError(f"a coded basis coefficient exceeds ±{MAX_MAGNITUDE}")

    def _check_coded_mu(self) -> None:
        """A coded μ: only in a coded layer, a grid exponent of 1 … 5, integers within the coder's range."""
        if self.prior is None:
            raise ValueError("a coded mu rides in an entropy-coded basis layer (prior) only")
        given = self.coded_mu
        if not isinstance(given, tuple) or len(given) != 2:
            raise ValueError(f"coded_mu must be (g, q), got {given!r}")
        coded_mu_codes(given[0], 1)  # the grid exponent's range
        q = np.asarray(given[1])
        if q.ndim != 1 or not len(q) or not np.issubdtype(q.dtype, np.integer):
            raise ValueError("a coded mu's integers must be a non-empty 1-D integer array")
        if int(np.abs(q.astype(np.int64)).max()) > MAX_MAGNITUDE:
            raise ValueError(f"a coded mu integer exceeds ±{MAX_MAGNITUDE}")

    def stream_codes(self) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """A coded layer's lead in its stream: the coded μ's integers and prior codes (empty without one), which
        come before the coefficients'."""
        if self.coded_mu is None:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        return mu_stream_lead(self.coded_mu)

    @functools.cached_property
    def _coded(self) -> bytes:
        """A coded layer's bytes: the step code, then the coder's bytes (§4.8), a coded μ's integers first (§4.9)."""
        assert self.prior is not None
        code = packed_step_code(self.step)
        codes = prior_codes(self.prior[0], self.prior[1], code, self.first, self.count)
        lead_q, lead_codes = self.stream_codes()
        return bytes([code]) + encode_integers(np.concatenate([lead_q, np.asarray(self.q, dtype=np.int64)]),
                                               np.concatenate([lead_codes, codes]))

    def _check_packed(self, q: np.ndarray) -> None:
        """The packed layer's own rules: top width, step code, integer fields of width ≥ 1 that hold q."""
        if isinstance(self.top, bool) or not isinstance(self.top, int | np.integer) or not (
                1 <= self.top <= MAX_TOP_WIDTH):
            raise ValueError(f"packed basis layer's top width must be an integer in [1, {MAX_TOP_WIDTH}], "
                             f"got {self.top!r}")
        packed_step_code(self.step)
        if q.ndim != 1 or not np.issubdtype(q.dtype, np.integer) or not 1 <= len(q) <= MAX_BASIS_COUNT:
            raise ValueError(f"basis coefficients must be 1 to {MAX_BASIS_COUNT} integers")
        if isinstance(self.first, bool) or not isinstance(self.first, int | np.integer) or self.first < 0:
            return  # refused with its message by the checks of every layer
        widths = packed_widths(self.top, self.first, len(q))
        if widths[-1] < 1:
            raise ValueError(f"a packed layer of top width {self.top} from vector {self.first} holds fewer than "
                             f"{len(q)} coefficients")
        low, high = -(1 << (widths - 1)), (1 << (widths - 1)) - 1
        if ((q < low) | (q > high)).any():
            raise ValueError("a packed coefficient does not fit its field")

    @property
    def count(self) -> int:
        """Number of coefficients k."""
        return len(self.q)

    @property
    def nbytes(self) -> int:
        """Stored size: the float16 step and k bytes; packed, the step code and the fields' bytes; coded, the step
        code and the coder's bytes."""
        if self.prior is not None:
            return len(self._coded)
        if self.top:
            return packed_bytes(self.top, self.first, self.count)
        return STEP_BYTES + self.count

    @property
    def data(self) -> bytes:
        """Payload bytes: the step as little-endian float16, then the k int8 coefficients; packed, the step
        code, then the fields (§4.7); coded, the step code, then the coder's bytes (§4.8)."""
        if self.prior is not None:
            return self._coded
        if self.top:
            widths = packed_widths(self.top, self.first, self.count)
            return bytes([packed_step_code(self.step)]) + pack_fields(self.q, widths)
        return int8_step_bytes(self.step, self.q)

    def coefficients(self) -> npt.NDArray[np.float32]:
        """``s · q`` as float32."""
        return dequantise_int8(self.step, self.q)

    def entry(self) -> dict[str, object]:
        """The ``layers.basis`` object of the record's index entry (``first`` and ``project`` only when not 0)."""
        entry: dict[str, object] = {"sha256": self.sha256, "count": self.count}
        if self.first:
            entry["first"] = int(self.first)
        if self.project:
            entry["project"] = int(self.project)
        if self.top:
            entry["top"] = int(self.top)
        if self.prior is not None:
            entry["prior"] = [int(self.prior[0]), int(self.prior[1])]
            entry["length"] = self.nbytes
        if self.coded_mu is not None:
            entry["mu_step"] = int(self.coded_mu[0])
        return entry

def quantise_coefficients(sha256: str, coefficients: npt.ArrayLike, first: int = 0, project: int = 0) -> BasisLayer:
    """A basis layer holding ``coefficients`` (of vectors ``first``, ``first + 1``, …) quantised to int8
    with one float16 step (max |c| / 127, :func:`int8_with_step`), over a base projected on ``project``
    vectors (0: not projected)."""
    step, q = int8_with_step(coefficients, "basis coefficients")
    return BasisLayer(sha256, step, q, int(first), int(project))

def packed_coefficients(sha256: str, coefficients: npt.ArrayLike, max_bytes: int, first: int = 0,
                        project: int = 0) -> BasisLayer | None:
    """A packed basis layer (format 2.3) of at most ``max_bytes`` closest to ``coefficients`` (of vectors
    ``first``, ``first + 1``, …; the leading ones that fit), over a base projected on ``project`` vectors;
    None when not even one coefficient fits (:func:`~brdfcodec.layers.packed.choose_packing`)."""
    choice = choose_packing(coefficients, int(first), int(max_bytes))
    if choice is None:
        return None
    return BasisLayer(sha256, packed_step(choice.step_code), choice.q, int(first), int(project), choice.top)

def coded_coefficients(sha256: str, coefficients: npt.ArrayLike, max_bytes: int, prior: tuple[int, int],
                       first: int = 0, project: int = 0, *, count: int | None = None,
                       coded_mu: tuple[int, npt.NDArray[np.int64]] | None = None) -> BasisLayer | None:
    """An entropy-coded basis layer (format 2.4) of at most ``max_bytes`` closest to ``coefficients`` (of vectors
    ``first``, …; the leading ones that fit, or exactly ``count`` of them), under the form's ``prior``, after a
    coded μ's integers when given (format 2.5: they take their bytes first); None when not even one coefficient
    fits (:func:`~brdfcodec.layers.coded_basis.choose_coding`)."""
    choice = choose_coding(coefficients, int(first), int(max_bytes), int(prior[0]), int(prior[1]), count=count,
                           lead=None if coded_mu is None else mu_stream_lead(coded_mu))
    if choice is None:
        return None
    return BasisLayer(sha256, packed_step(choice.step_code), choice.q, int(first), int(project),
                      prior=(int(prior[0]), int(prior[1])), coded_mu=coded_mu)

#: Said of a short reference (format 2.6) that names no basis of the model, or more than one.
_SHORT_NOTE = " (a short reference: the first 8 bytes of a SHA-256, which name none of the model's bases, or two)"


def check_basis_layers(
    entries: Sequence[Any], basis_named: Callable[[str], SharedBasis | None], where: str, own: str | None
) -> None:
    """Refuse, when a file is opened for decoding, a record whose basis layer its model cannot decode.

    Parameters
    ----------
    entries : sequence of RecordEntry
        A file's index (:attr:`brdfcodec.format.bvae.BvaeHeader.entries`).
    basis_named : callable
        The model's shared basis with a SHA-256, or None when the model has none by that hash.
    where : str
        The file, for the messages.
    own : str or None
        SHA-256 of the model's current shared basis (None: it has none), for the messages.

    Raises
    ------
    BasisMismatchError
        A record names a shared basis the model does not have (naming both hashes).
    BasisError
        A record's ``first + count`` or ``project`` exceeds the vectors its shared basis holds.
    """
    for entry in entries:
        layer = (entry.layers or {}).get("basis")
        if layer is None:
            continue
        sha = str(layer["sha256"])
        basis = basis_named(sha)
        if basis is None:
            raise BasisMismatchError(
                f"{where}: record {entry.name!r}: its basis layer needs shared basis {sha}"
                f"{_SHORT_NOTE if len(sha) < 64 else ''}, but the decoder's model "
                f"has {own or 'none'}; decode it with the model that wrote it"
            )
        count, first, project = int(layer["count"]), int(layer.get("first", 0)), int(layer.get("project", 0))
        if first + count > basis.count:
            raise BasisError(
                f"{where}: record {entry.name!r}: its basis layer uses vectors {first + 1} to {first + count}, but "
                f"shared basis {sha[:12]}… holds {basis.count}"
            )
        if project > basis.count:
            raise BasisError(
                f"{where}: record {entry.name!r}: its base is projected on {project} basis vectors, but shared "
                f"basis {sha[:12]}… holds {basis.count}"
            )

def check_records_without_latent(
    entries: Sequence[Any], basis_named: Callable[[str], SharedBasis | None], where: str, linear_path: bool
) -> None:
    """Refuse, when a file is opened for decoding, a record without a latent (format 2.1) whose decoder cannot
    give its base: the decoder's linear-path mean must cover every entry of the shared basis
    (``spec/bvae-format.md`` §4.6). Torch-free (``bvae info``); the decoder itself checks its own network.

    Parameters
    ----------
    entries : sequence of RecordEntry
        A file's index, its basis layers already checked (:func:`check_basis_layers`).
    basis_named : callable
        As for :func:`check_basis_layers`.
    where : str
        The file, for the messages.
    linear_path : bool
        Whether the decoder has a linear path (``ModelConfig.linear_basis``).

    Raises
    ------
    BasisError
        Naming the file and the record.
    """
    for entry in entries:
        layers = entry.layers or {}
        if layers.get("mu") != "none":
            continue
        problem = None
        if not linear_path:
            problem = "the decoder has no linear path"
        else:
            basis = basis_named(str(layers["basis"]["sha256"]))
            if basis is not None and not np.isin(basis.entries, linear_path_entries()).all():
                problem = "the decoder's linear path does not cover every entry of the shared basis"
        if problem is not None:
            raise BasisError(f"{where}: record {entry.name!r} has no latent (format 2.1) and decodes from the "
                             f"decoder's linear-path mean, but {problem}")

def basis_layer_from_bytes(entry: Mapping[str, Any], data: bytes, latent_dim: int = 0) -> BasisLayer:
    """A basis layer from its validated index entry and its payload bytes (``latent_dim``: the file's D, the
    integers of a coded μ, ``entry["mu_step"]``, that come first in a coded layer's stream)."""
    count = int(entry["count"])
    top, first = int(entry.get("top", 0)), int(entry.get("first", 0))
    if "prior" in entry:
        prior = (int(entry["prior"][0]), int(entry["prior"][1]))
        if not CODED_HEADER_BYTES <= len(data) <= MAX_CODED_BYTES:
            raise ValueError(f"coded basis layer holds {len(data)} bytes, expected 1 to {MAX_CODED_BYTES}")
        codes = prior_codes(prior[0], prior[1], data[0], first, count)
        coded_mu = None
        if "mu_step" in entry:
            g = int(entry["mu_step"])
            codes = np.concatenate([coded_mu_codes(g, latent_dim), codes])
        q = decode_integers(data[CODED_HEADER_BYTES:], codes)
        if "mu_step" in entry:
            coded_mu, q = (int(entry["mu_step"]), q[:latent_dim]), q[latent_dim:]
        layer = BasisLayer(str(entry["sha256"]), packed_step(data[0]), q, first, int(entry.get("project", 0)),
                           prior=prior, coded_mu=coded_mu)
        if layer.data != bytes(data):
            raise ValueError("a coded basis layer's bytes are not the shortest coding of its integers (§4.8)")
        return layer
    if top:
        if len(data) != packed_bytes(top, first, count):
            raise ValueError(f"packed basis layer holds {len(data)} bytes, expected {packed_bytes(top, first, count)}")
        q = unpack_fields(data[PACKED_HEADER_BYTES:], packed_widths(top, first, count))
        return BasisLayer(str(entry["sha256"]), packed_step(data[0]), q, first, int(entry.get("project", 0)), top)
    if len(data) != STEP_BYTES + count:
        raise ValueError(f"basis layer holds {len(data)} bytes, expected {STEP_BYTES + count}")
    step, q = int8_from_step_bytes(data, "basis step")
    return BasisLayer(str(entry["sha256"]), step, q, int(entry.get("first", 0)), int(entry.get("project", 0)))
