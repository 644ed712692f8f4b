"""The shared basis, dense or factorised (``spec/model.md`` §1.4).

Principal directions of mapped materials, which every basis layer weighs.

Part of :mod:`brdfcodec.layers.basis`, which gathers the names of its parts.
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import N_CHANNELS, N_KEPT_SLICES, NETWORK_INPUT_SHAPE
from brdfcodec.errors import BasisError
from brdfcodec.layers.colour_orders_pca import colour_orders_pca
from brdfcodec.layers.quantise import _COLUMN_BLOCK, _ENTRIES_PER_CHANNEL, _N_ENTRIES, MAX_BASIS_COUNT

#: Entries of one kept slice in one colour's block of the network layout (90 θh × 90 θd).
_SLICE_ENTRIES = NETWORK_INPUT_SHAPE[1] * NETWORK_INPUT_SHAPE[2]

__all__ = [
    "FactorisedBasis",
    "SharedBasis",
    "basis_offset",
    "extend_factorised_basis",
    "fit_factorised_basis",
    "fit_shared_basis",
    "quantise_factors",
    "shared_basis_rank",
    "with_colour_permutations",
]


@dataclass(frozen=True, eq=False)
class SharedBasis:
    """A model's shared basis.

    Attributes
    ----------
    components : ndarray of float16, shape (K, E), or None
        Orthonormal rows (up to float16 rounding) over ``entries``, as a dense basis file stores them; None
        for a factorised file (``factorised``), whose vectors are never stored dense.
    entries : ndarray of int64, shape (E,)
        Strictly increasing flat positions in the ``(63, 90, 90)`` network layout.
    sha256 : str
        SHA-256 of the file it was read from (its identity in records).
    factorised : FactorisedBasis or None
        The factors of a factorised basis file (``spec/model.md`` §5); its vectors are the binary32 products
        of colour vector and factor. Sums over the vectors are taken on the factors: a third of the memory
        traffic of the dense vectors, which bounds a layered decode's time.
    """

    components: npt.NDArray[np.float16] | None
    entries: npt.NDArray[np.int64]
    sha256: str
    factorised: FactorisedBasis | None = None

    def __post_init__(self) -> None:
        if (self.components is None) == (self.factorised is None):
            raise ValueError("a shared basis is either dense (components) or factorised, not both or neither")

    @property
    def count(self) -> int:
        """Number of vectors K."""
        if self.factorised is not None:
            return len(self.factorised.colours)
        assert self.components is not None
        return int(self.components.shape[0])

    @functools.cached_property
    def _float32(self) -> npt.NDArray[np.float32]:
        """Every vector in float32, dense (cached: encoders fit on them again and again)."""
        if self.factorised is not None:
            return self.factorised.products(0, self.count)
        assert self.components is not None
        return self.components.astype(np.float32)

    @functools.cached_property
    def _channel_of_entry(self) -> npt.NDArray[np.int64]:
        return self.entries // _ENTRIES_PER_CHANNEL

    @property
    def entry_mask(self) -> npt.NDArray[np.bool_]:
        """``entries`` as a flat boolean mask over the ``(63, 90, 90)`` layout (read-only)."""
        return self._entry_mask

    @functools.cached_property
    def _entry_mask(self) -> npt.NDArray[np.bool_]:
        """``entries`` as a flat boolean mask (scattering through it is twice as fast as through the indices)."""
        if np.any(np.diff(self.entries) <= 0):  # a mask scatters in increasing order only
            raise BasisError(f"shared basis {self.sha256[:12]}: 'entries' must be strictly increasing")
        mask = np.zeros(_N_ENTRIES, dtype=bool)
        mask[self.entries] = True
        mask.setflags(write=False)
        return mask

    def vectors(self, first: int, k: int) -> npt.NDArray[np.float32]:
        """The vectors ``first … first + k − 1`` as a read-only float32 ``(k, E)`` array.

        Dense in memory (a factorised basis is expanded once and kept): for encoders. Decoders sum over the
        vectors with :meth:`weighted_sum` and :meth:`dots` instead.
        """
        view = self._float32[self._rows(first, k)]
        view.setflags(write=False)
        return view

    def vectors_uncached(self, first: int, k: int) -> npt.NDArray[np.float32]:
        """:meth:`vectors` without keeping a dense copy of a factorised basis (for one-off passes)."""
        if self.factorised is None or "_float32" in self.__dict__:
            return self.vectors(first, k)
        rows = self._rows(first, k)
        return self.factorised.products(rows.start, rows.stop - rows.start)

    def vector_values(self, count: int, positions: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Values of the first ``count`` vectors at a few ``positions`` (indices into ``entries``), ``(count, n)``."""
        rows = self._rows(0, count)
        where = np.asarray(positions, dtype=np.int64)
        if self.factorised is None:
            return self._float32[rows][:, where] if "_float32" in self.__dict__ else (
                self.components[rows][:, where].astype(np.float32))  # type: ignore[index]
        return self.factorised.values_at(count, where)

    def weighted_sum(self, weights: npt.ArrayLike, first: int = 0) -> npt.NDArray[np.float32]:
        """``Σᵢ wᵢ · b_(first+i)`` over ``entries``, shape (E,), float32, on the calling thread (the sum is bound
        by memory bandwidth; a factorised basis is summed on its factors).

        Parameters
        ----------
        weights : array_like, shape (k,)
            One weight per vector ``first … first + k − 1``.
        first : int, default 0
        """
        w = np.asarray(weights, dtype=np.float32).reshape(-1)
        rows = self._rows(first, len(w))
        if self.factorised is None:
            return w @ self.vectors(rows.start, len(w))
        width = self.factorised.width
        out = np.empty((N_CHANNELS, width), dtype=np.float32)
        self.factorised.combine(self.factorised.fold(w, rows.start), slice(0, width), out)
        return out.reshape(-1)

    def dots(self, values: npt.ArrayLike, count: int) -> npt.NDArray[np.float32]:
        """Dot products of ``values`` over ``entries`` with the first ``count`` vectors.

        Parameters
        ----------
        values : array_like, shape (E,) or (B, E)
        count : int

        Returns
        -------
        ndarray of float32, shape (count,) or (B, count)
        """
        y = np.asarray(values, dtype=np.float32)
        rows = self._rows(0, count)
        if self.factorised is None:
            return y @ self.vectors(0, count).T
        return self.factorised.dots(y, rows.stop)

    def on_grid(self, values: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Values over ``entries``, shape (E,), placed in the ``(63, 90, 90)`` layout (0 elsewhere)."""
        out = np.zeros(_N_ENTRIES, dtype=np.float32)
        out[self._entry_mask] = values
        return out.reshape(NETWORK_INPUT_SHAPE)

    def residual(self, coefficients: npt.ArrayLike, first: int = 0) -> npt.NDArray[np.float32]:
        """``Σᵢ cᵢ · b_(first+i)`` in the ``(63, 90, 90)`` layout (0 off the basis' entries), mapped units.

        Parameters
        ----------
        coefficients : array_like, shape (k,)
            Coefficients of k consecutive vectors.
        first : int, default 0
            Index of the first of those vectors (``first + k`` ≤ K).
        """
        return self.on_grid(self.weighted_sum(coefficients, first))

    def residual_channels(
        self, coefficients: npt.ArrayLike, channels: Sequence[int], first: int = 0
    ) -> npt.NDArray[np.float32]:
        """Only some channels of :meth:`residual`, shape ``(len(channels), 90, 90)`` (partial decoding)."""
        c = np.asarray(coefficients, dtype=np.float32).reshape(-1)
        rows = self._rows(first, len(c))
        wanted = np.asarray(channels, dtype=np.int64)
        out = np.zeros((len(wanted), _ENTRIES_PER_CHANNEL), dtype=np.float32)
        factorised = self.factorised
        folded = None if factorised is None else factorised.fold(c, rows.start)
        for row, channel in enumerate(wanted):
            start, stop = np.searchsorted(self._channel_of_entry, [channel, channel + 1])
            if stop <= start:
                continue
            target = self.entries[start:stop] - channel * _ENTRIES_PER_CHANNEL
            if factorised is None or folded is None:
                out[row, target] = c @ self.vectors(rows.start, len(c))[:, start:stop]
            else:  # entries of colour k are k·P … k·P + P − 1 in order
                colour = int(channel) // N_KEPT_SLICES
                width = factorised.width
                part = slice(start - colour * width, stop - colour * width)
                out[row, target] = folded[:, colour] @ factorised.factors32[:, part]
        return out.reshape(len(wanted), *NETWORK_INPUT_SHAPE[1:])

    def project(self, values: npt.ArrayLike, centre: npt.ArrayLike, count: int) -> npt.NDArray[np.float32]:
        """Values over ``entries`` projected around ``centre`` on the first ``count`` vectors (a projected base,
        ``spec/bvae-format.md`` §4.5): ``m + Σⱼ ((y − m) · b_j) b_j``, j = 0 … count − 1.

        Parameters
        ----------
        values : array_like, shape (E,) or (B, E)
            y: a clamped base decode at the basis' entries, mapped units.
        centre : array_like, shape (E,)
            m: the decoder's linear-path mean at the same entries.
        count : int
            P, in [1, K].

        Returns
        -------
        ndarray of float32, the shape of ``values``
        """
        m = np.asarray(centre, dtype=np.float32)
        y = np.asarray(values, dtype=np.float32)
        a = self.dots(y - m, count)
        if a.ndim == 1:
            return m + self.weighted_sum(a)
        return m + np.stack([self.weighted_sum(row) for row in a])

    def leading(self, count: int, sha256: str) -> SharedBasis:
        """The first ``count`` vectors, as the basis named ``sha256`` whose vectors they are (a model's
        ``basis_prefixes``, ``spec/model.md`` §5): the same arrays, no copy.

        Raises
        ------
        BasisError
            ``count`` outside 1 … K.
        """
        self._rows(0, count)
        made = self.__dict__.setdefault("_leading", {})  # one view per earlier basis: decoders ask per record
        if (count, sha256) in made:
            return made[count, sha256]
        if self.factorised is None:
            assert self.components is not None
            part = SharedBasis(self.components[:count], self.entries, sha256)
        else:
            f = self.factorised
            used = int(f.factor_of[:count].max()) + 1
            fine = len(f.factors)
            if used <= fine or f.factors_int8 is None or f.factor_slice_scales is None:
                factors = FactorisedBasis(f.factors[:used], f.colours[:count], f.factor_of[:count], f.colour_entries)
            else:
                factors = FactorisedBasis(f.factors, f.colours[:count], f.factor_of[:count], f.colour_entries,
                                          f.factors_int8[:used - fine], f.factor_slice_scales[:used - fine])
            factors.__dict__["factors32"] = f.factors32[:used]  # the widened factors, shared rather than made again
            part = SharedBasis(None, self.entries, sha256, factors)
        made[count, sha256] = part
        return part

    def check_vectors(self, first: int, k: int) -> None:
        """Refuse (:class:`BasisError`, with the sizes) unless vectors ``first … first + k − 1`` exist."""
        self._rows(first, k)

    def _rows(self, first: int, k: int) -> slice:
        """The vectors ``first … first + k − 1``, refused unless they exist."""
        if not (1 <= k and 0 <= first and first + k <= self.count):
            raise BasisError(
                f"a basis layer of {k} coefficients from vector {first} needs vectors {first} to {first + k - 1}, "
                f"but this basis holds {self.count}"
            )
        return slice(first, first + k)

def fit_shared_basis(
    inputs: npt.ArrayLike, masks: npt.ArrayLike, count: int, *, colour_permutations: bool = False
) -> tuple[npt.NDArray[np.float16], npt.NDArray[np.int64]]:
    """Principal components of training materials' mapped kept slices, over the entries valid in all of them.

    Parameters
    ----------
    inputs : array_like, shape (N, 63, 90, 90)
        Mapped kept slices (network inputs) of the training materials.
    masks : array_like of bool, shape (N, 63, 90, 90)
        Their valid entries; the basis covers the entries valid in every material
        (with ``colour_permutations``, valid in every colour of every material).
    count : int
        K, in [1, :func:`shared_basis_rank` (N, colour_permutations)]: no more
        vectors than the centred data has dimensions.
    colour_permutations : bool, default False
        Fit on the materials in all 6 orders of their colour channels
        (:func:`with_colour_permutations`) instead of as measured. The 6N
        materials are not made: :func:`~brdfcodec.layers.colour_orders_pca.colour_orders_pca`
        finds their components from the colour sums and deviations (the same
        components up to rotations within pairs of equal singular values).

    Returns
    -------
    components : ndarray of float16, shape (K, E)
    entries : ndarray of int64, shape (E,)
    """
    inputs, masks = np.asarray(inputs), np.asarray(masks, dtype=bool)
    n = len(inputs)
    limit = min(shared_basis_rank(n, colour_permutations), MAX_BASIS_COUNT)
    if not 1 <= count <= limit:
        orders = " in 6 colour orders" if colour_permutations else ""
        raise ValueError(f"count must be in [1, {limit}] for {n} materials{orders}")
    if colour_permutations:
        return fit_factorised_basis(inputs, masks, count).expand()
    entries = np.flatnonzero(masks.reshape(n, -1).all(axis=0)).astype(np.int64)
    data = inputs.reshape(len(inputs), -1)[:, entries].astype(np.float64)
    data -= data.mean(axis=0)
    _, _, vt = np.linalg.svd(data, full_matrices=False)
    return vt[:count].astype(np.float16), entries

@dataclass(frozen=True, eq=False)
class FactorisedBasis:
    """A shared basis fitted on colour-permuted materials, stored as its factors (``spec/model.md`` §5).

    Every vector of such a basis is a colour vector times a vector over one colour's entries
    (:mod:`brdfcodec.layers.colour_orders_pca`), and the two vectors of a chroma pair share the latter, so the
    factors take about a third of the dense vectors' bytes.

    Vector k's value at entry ``c · P + e`` (colour c, column e) is the binary32 product
    ``COLOUR_VECTORS[colours[k], c] · factors[factor_of[k], e]`` (:meth:`products`). Sums over the vectors are
    taken on the factors (:meth:`fold`, then :meth:`combine`; :meth:`dots`), which read a third of the memory
    the dense vectors would.

    Factor rows ``0 … F₀ − 1`` are stored in binary16 (``factors``); a basis extended in place may hold more,
    ``F₀ … F − 1``, in 8 bits (since ``spec/model.md`` 1.11): row ``F₀ + i`` at column e is the binary32 product
    ``factors_int8[i, e] · factor_slice_scales[i, colour_entries[e] // 8100]``, one scale per kept slice.

    Attributes
    ----------
    factors : ndarray of float16, shape (F₀, P)
        Vectors over one colour's entries (F₀ ≥ 1).
    colours : ndarray of int64, shape (K,)
        Each basis vector's colour vector, a row of
        :data:`~brdfcodec.layers.colour_orders_pca.COLOUR_VECTORS` (0: (1, 1, 1)/√3, 1: (1, −1, 0)/√2,
        2: (1, 1, −2)/√6).
    factor_of : ndarray of int64, shape (K,)
        Each basis vector's row of ``factors``.
    colour_entries : ndarray of int64, shape (P,)
        Strictly increasing positions within one colour's block of the network layout
        (``21 · 90 · 90`` entries); the basis covers them in every colour.
    factors_int8 : ndarray of int8, shape (F − F₀, P), or None
        The later factor rows in 8 bits, with ``factor_slice_scales``.
    factor_slice_scales : ndarray of float32, shape (F − F₀, 21), or None
        Positive scales of ``factors_int8``, per row and kept slice (``colour_entries // (90 · 90)``).
    """

    factors: npt.NDArray[np.float16]
    colours: npt.NDArray[np.int64]
    factor_of: npt.NDArray[np.int64]
    colour_entries: npt.NDArray[np.int64]
    factors_int8: npt.NDArray[np.int8] | None = None
    factor_slice_scales: npt.NDArray[np.float32] | None = None

    @property
    def factor_count(self) -> int:
        """F: the factor rows, binary16 and 8-bit together."""
        return len(self.factors) + (0 if self.factors_int8 is None else len(self.factors_int8))

    @property
    def width(self) -> int:
        """P: the entries of one colour every factor covers."""
        return int(self.factors.shape[1])

    @functools.cached_property
    def factors32(self) -> npt.NDArray[np.float32]:
        """Every factor row in float32, ``(F, P)``: the binary16 rows widened, the 8-bit rows times their
        slice scales (read-only, cached)."""
        widened = self.factors.astype(np.float32)
        if self.factors_int8 is not None and self.factor_slice_scales is not None:
            scales = self.factor_slice_scales.astype(np.float32)[:, self.colour_entries // _SLICE_ENTRIES]
            widened = np.concatenate([widened, self.factors_int8.astype(np.float32) * scales])
        widened.setflags(write=False)
        return widened

    @functools.cached_property
    def _colour_vectors(self) -> npt.NDArray[np.float32]:
        """Each vector's colour vector in binary32, ``(K, 3)``."""
        from brdfcodec.layers.colour_orders_pca import COLOUR_VECTORS

        return COLOUR_VECTORS.astype(np.float32)[self.colours]

    def products(self, first: int, k: int) -> npt.NDArray[np.float32]:
        """Vectors ``first … first + k − 1`` as the spec defines them (``spec/model.md`` §5): colour vector times
        factor, each product in binary32, over the entries ``c · 21 · 90 · 90 + colour_entries`` (colour c = 0, 1,
        2, in that order); shape ``(k, 3 · P)``."""
        rows = slice(first, first + k)
        colours = self._colour_vectors[rows]
        factors = self.factors32[self.factor_of[rows]]
        return (colours[:, :, None] * factors[:, None, :]).reshape(len(colours), -1)

    def values_at(self, count: int, positions: npt.NDArray[np.int64]) -> npt.NDArray[np.float32]:
        """Values of vectors ``0 … count − 1`` at ``positions`` (indices into the ``3 · P`` entries), ``(count, n)``."""
        width = self.width
        colour, column = np.divmod(positions, width)
        return self._colour_vectors[:count][:, colour] * self.factors32[self.factor_of[:count]][:, column]

    def fold(self, weights: npt.NDArray[np.float32], first: int) -> npt.NDArray[np.float32]:
        """Weights of vectors ``first …`` gathered per factor and colour: ``W[f, c] = Σ wᵢ · colourᵢ[c]`` over the
        vectors i of factor f, shape ``(F, 3)``; ``Σᵢ wᵢ vᵢ`` is then ``Wᵀ @ factors`` (:meth:`combine`)."""
        rows = slice(first, first + len(weights))
        folded = np.zeros((self.factor_count, N_CHANNELS), dtype=np.float32)
        np.add.at(folded, self.factor_of[rows], weights[:, None] * self._colour_vectors[rows])
        return folded

    def combine(self, folded: npt.NDArray[np.float32], columns: slice, out: npt.NDArray[np.float32]) -> None:
        """``out[:, columns] = foldedᵀ @ factors[:, columns]`` (``out`` of shape ``(3, P)``), column block by column
        block so that each block of the factors is read from memory once for all three colours; only the factors
        with nonzero weights are read."""
        used = np.flatnonzero(np.any(folded != 0, axis=1))
        if used.size == 0:
            out[:, columns] = 0.0
            return
        rows = slice(int(used[0]), int(used[-1]) + 1)
        weights = np.ascontiguousarray(folded[rows].T)  # (3, F')
        factors = self.factors32[rows]
        for start in range(columns.start, columns.stop, _COLUMN_BLOCK):
            block = slice(start, min(start + _COLUMN_BLOCK, columns.stop))
            part = factors[:, block]
            for colour in range(N_CHANNELS):
                np.matmul(weights[colour], part, out=out[colour, block])

    def dots(self, values: npt.NDArray[np.float32], count: int) -> npt.NDArray[np.float32]:
        """Dot products of ``values`` (``(3 · P,)`` or ``(B, 3 · P)``) with vectors ``0 … count − 1``:
        per factor and colour first (``factors @ valuesᵀ``), then combined with each vector's colour vector."""
        width = self.width
        y = values.reshape(-1, N_CHANNELS, width)
        used = int(self.factor_of[:count].max()) + 1
        factors = self.factors32[:used]
        per_factor = np.zeros((len(y), used, N_CHANNELS), dtype=np.float32)
        for start in range(0, width, _COLUMN_BLOCK):
            block = slice(start, min(start + _COLUMN_BLOCK, width))
            part = factors[:, block]
            for b in range(len(y)):
                per_factor[b] += part @ y[b, :, block].T
        out = np.einsum("bkc,kc->bk", per_factor[:, self.factor_of[:count]], self._colour_vectors[:count])
        return out.reshape(values.shape[:-1] + (count,)).astype(np.float32, copy=False)

    def expand(self) -> tuple[npt.NDArray[np.float16], npt.NDArray[np.int64]]:
        """The basis in the dense layout: :meth:`products` rounded to float16 (what a dense file of the same
        vectors would hold), and its entries ``c · 21 · 90 · 90 + colour_entries``."""
        return self.products(0, len(self.colours)).astype(np.float16), self.entries()

    def entries(self) -> npt.NDArray[np.int64]:
        """The flat positions of the vectors' entries in the ``(63, 90, 90)`` layout, colour by colour."""
        block = _N_ENTRIES // N_CHANNELS
        return np.concatenate([c * block + self.colour_entries for c in range(N_CHANNELS)]).astype(np.int64)

def fit_factorised_basis(inputs: npt.ArrayLike, masks: npt.ArrayLike, count: int) -> FactorisedBasis:
    """:func:`fit_shared_basis` with ``colour_permutations``, as factors (what ``bvae model export`` writes).

    An entry is kept where it is valid in all three colours of every training material (permutations move
    colours onto each other's entries).
    """
    inputs, masks = np.asarray(inputs), np.asarray(masks, dtype=bool)
    n = len(inputs)
    valid = masks.reshape(n, -1).all(axis=0)
    colour_entries = np.flatnonzero(valid.reshape(N_CHANNELS, -1).all(axis=0)).astype(np.int64)
    values = inputs.reshape(n, N_CHANNELS, -1)[:, :, colour_entries]
    # The 6 orders' principal components, found without making them (brdfcodec.layers.colour_orders_pca).
    fit = colour_orders_pca(values, count)
    return FactorisedBasis(fit.factors.astype(np.float16), fit.colours, fit.factor_of, colour_entries)

def extend_factorised_basis(current: FactorisedBasis, fitted: FactorisedBasis,
                            storage: Literal["int8", "float16"] = "int8") -> FactorisedBasis:
    """``current`` followed by the vectors of ``fitted`` past its size: a larger basis whose leading vectors are
    ``current``'s, bit for bit (``spec/model.md`` §5, ``basis_prefixes``).

    ``fitted`` is a fit of the same materials with more vectors (:func:`fit_factorised_basis`), so its first
    vectors span what ``current``'s do, up to rounding. Its later vectors are kept in their order: a chroma
    vector whose pair partner ``current`` already holds shares that partner's factor; every other new factor is
    made orthogonal, in binary64, to the factors of its colour kind (grey, or chroma) already in the basis, then
    normalised and stored in ``storage``: 8 bits with a scale per kept slice (the default,
    :func:`quantise_factors`: half the bytes of binary16, each value within half its slice's step) or
    binary16; the basis stays orthonormal up to that rounding.

    Raises
    ------
    BasisError
        The two cover other entries, ``fitted`` holds no more vectors than ``current``, or binary16 rows
        would follow ``current``'s 8-bit ones.
    """
    size = len(current.colours)
    if not np.array_equal(current.colour_entries, fitted.colour_entries):
        raise BasisError("the fitted basis covers other entries than the current one: it was fitted on other "
                         "materials, and cannot extend it")
    if len(fitted.colours) <= size:
        raise BasisError(f"the fitted basis holds {len(fitted.colours)} vectors; extending one of {size} needs more")
    if storage == "float16" and current.factors_int8 is not None:
        raise BasisError("the current basis stores factors in 8 bits; binary16 factors cannot follow them")
    factors = [np.asarray(f, dtype=np.float64) for f in current.factors32]
    kinds = [int(current.colours[np.flatnonzero(current.factor_of == i)[0]] > 0) for i in range(len(factors))]
    colours, factor_of = list(current.colours), list(current.factor_of)
    row_of_fitted: dict[int, int] = {}  # a fitted factor's row in the extended basis
    if size and fitted.colours[size] > 0 and fitted.factor_of[size] == fitted.factor_of[size - 1]:
        # a chroma pair split at the end: its partner shares the current basis' last factor, where that is the
        # same factor (the fit repeats the current basis, as when both are fits of the same materials)
        last = int(current.factor_of[size - 1])
        same = abs(float(factors[last] @ fitted.factors[int(fitted.factor_of[size])].astype(np.float64)))
        if current.colours[size - 1] > 0 and same > 0.999:
            row_of_fitted[int(fitted.factor_of[size])] = last
    for k in range(size, len(fitted.colours)):
        source = int(fitted.factor_of[k])
        if source not in row_of_fitted:
            kind = int(fitted.colours[k] > 0)
            u = fitted.factors[source].astype(np.float64)
            for _ in range(2):  # Gram–Schmidt twice: orthogonal to binary64 precision
                for row, row_kind in zip(factors, kinds, strict=True):
                    if row_kind == kind:
                        u -= (u @ row) / (row @ row) * row
            norm = float(np.linalg.norm(u))
            if not norm > 1e-3:
                raise BasisError(f"fitted vector {k + 1} lies in the span of the current basis: nothing to add")
            factors.append(u / norm)
            kinds.append(kind)
            row_of_fitted[source] = len(factors) - 1
        colours.append(int(fitted.colours[k]))
        factor_of.append(row_of_fitted[source])
    new = np.asarray(factors[current.factor_count:]).reshape(-1, current.width)
    colours_, factor_of_ = np.asarray(colours, dtype=np.int64), np.asarray(factor_of, dtype=np.int64)
    if storage == "float16":
        return FactorisedBasis(np.concatenate([current.factors, new.astype(np.float16)]), colours_, factor_of_,
                               current.colour_entries)
    coarse, scales = quantise_factors(new, current.colour_entries)
    if current.factors_int8 is not None and current.factor_slice_scales is not None:
        coarse = np.concatenate([current.factors_int8, coarse])
        scales = np.concatenate([current.factor_slice_scales, scales])
    return FactorisedBasis(current.factors, colours_, factor_of_, current.colour_entries, coarse, scales)


def quantise_factors(factors: npt.ArrayLike, colour_entries: npt.NDArray[np.int64]
                     ) -> tuple[npt.NDArray[np.int8], npt.NDArray[np.float32]]:
    """Factor rows in 8 bits (``spec/model.md`` §5, since 1.11): per row and kept slice, the scale is the largest
    magnitude over 127 (1 where the slice has no entry or only zeros), and each value the nearest integer to value
    over scale, in −127 … 127.

    Parameters
    ----------
    factors : array_like, shape (F, P)
        Factor rows (unit vectors, dimensionless).
    colour_entries : ndarray of int64, shape (P,)
        Their columns' positions in one colour's block, ``21 · 90 · 90`` entries.

    Returns
    -------
    (ndarray of int8, shape (F, P), ndarray of float32, shape (F, 21))
    """
    values = np.asarray(factors, dtype=np.float64)
    slice_of = colour_entries // _SLICE_ENTRIES
    scales = np.ones((len(values), N_KEPT_SLICES), dtype=np.float32)
    for kept in range(N_KEPT_SLICES):
        columns = slice_of == kept
        if columns.any():
            largest = np.abs(values[:, columns]).max(axis=1) / 127.0
            scales[:, kept] = np.where(largest > 0, largest, 1.0).astype(np.float32)
    quantised = np.clip(np.rint(values / scales[:, slice_of].astype(np.float64)), -127, 127).astype(np.int8)
    return quantised, scales

def shared_basis_rank(materials: int, colour_permutations: bool = False) -> int:
    """Most vectors a shared basis fitted on ``materials`` training materials can have: the rank of the centred data.

    N − 1 for the materials as measured. With their 6 colour orders, 5N − 1, not 6N − 1: at each entry the
    permutations of a material's (R, G, B) span its grey part and the 2-D space of colour differences, and the
    6 orders of one material span at most 1 + 2 × 2 = 5 dimensions (the permutation representation of the
    symmetric group on 3 colours holds no sign representation).
    """
    return max(0, (5 * materials if colour_permutations else materials) - 1)

def with_colour_permutations(stack: npt.ArrayLike) -> np.ndarray:
    """Materials in the network layout followed by their 5 other colour orders.

    Because the log mapping is the same function of reflectance in every
    channel, exchanging the mapped R, G and B blocks (channel ``k`` is colour
    ``k // 21``) exchanges reflectances exactly: each permuted material is a
    valid one with other colours (the augmentation training uses,
    :func:`brdfcodec.training.augment.permute_colours`).

    Parameters
    ----------
    stack : array_like, shape (N, 63, 90, 90)
        Mapped inputs or their masks.

    Returns
    -------
    ndarray, shape (6N, 63, 90, 90)
        Order (R, G, B) first (the materials as given), then the other 5 orders in
        :func:`itertools.permutations` order, N materials each.
    """
    stack = np.asarray(stack)
    if stack.ndim != 4 or stack.shape[1:] != NETWORK_INPUT_SHAPE:
        raise ValueError(f"expected a stack of shape (N, {', '.join(map(str, NETWORK_INPUT_SHAPE))}), "
                         f"got {stack.shape}")
    grouped = stack.reshape(len(stack), N_CHANNELS, N_KEPT_SLICES, *NETWORK_INPUT_SHAPE[1:])
    return np.concatenate([grouped[:, list(order)].reshape(stack.shape)
                           for order in itertools.permutations(range(N_CHANNELS))])

_FACTORISED_TENSORS = ("factors", "colours", "factor_of", "colour_entries")

def _factorised(tensors: Mapping[str, np.ndarray], where: str) -> FactorisedBasis:
    """A factorised basis from a file's tensors, refused unless every index is in range."""
    missing = [name for name in _FACTORISED_TENSORS if name not in tensors]
    if missing:
        raise BasisError(f"{where}: a factorised basis file also needs the tensors {missing}")
    factors, colours, factor_of, colour_entries = (tensors[name] for name in _FACTORISED_TENSORS)
    if factors.dtype != np.float16 or factors.ndim != 2 or factors.shape[0] == 0:
        raise BasisError(f"{where}: 'factors' must be a 2-D float16 tensor, got {factors.dtype} {factors.shape}")
    integer = all(t.ndim == 1 and t.dtype.kind in "iu" for t in (colours, factor_of, colour_entries))
    if not integer or colours.shape != factor_of.shape or colour_entries.shape[0] != factors.shape[1]:
        raise BasisError(f"{where}: 'colours' and 'factor_of' must be 1-D integers, one per vector, and "
                         "'colour_entries' 1-D integers, one per factor column")
    if not 1 <= colours.shape[0] <= MAX_BASIS_COUNT:  # checked before expanding: K × 3P floats
        raise BasisError(f"{where}: 'colours' lists {colours.shape[0]} vectors; a basis holds 1 to {MAX_BASIS_COUNT}")
    if colours.min() < 0 or colours.max() > 2:
        raise BasisError(f"{where}: 'colours' must be 0 (grey), 1 or 2 (chroma)")
    if factor_of.size and factor_of.min() < 0:
        raise BasisError(f"{where}: 'factor_of' must name factor rows, from 0")
    block = _N_ENTRIES // N_CHANNELS
    if colour_entries.min() < 0 or colour_entries.max() >= block or np.any(np.diff(colour_entries) <= 0):
        raise BasisError(f"{where}: 'colour_entries' must be strictly increasing positions in [0, {block})")
    if not np.isfinite(factors).all():
        raise BasisError(f"{where}: 'factors' holds non-finite values")
    coarse, scales = tensors.get("factors_int8"), tensors.get("factor_slice_scales")
    if (coarse is None) != (scales is None):
        raise BasisError(f"{where}: 'factors_int8' and 'factor_slice_scales' come together")
    rows = factors.shape[0]
    if coarse is not None and scales is not None:
        if coarse.dtype != np.int8 or coarse.ndim != 2 or coarse.shape[0] == 0 or coarse.shape[1] != factors.shape[1]:
            raise BasisError(f"{where}: 'factors_int8' must be a 2-D int8 tensor with the {factors.shape[1]} "
                             f"columns of 'factors', got {coarse.dtype} {coarse.shape}")
        if scales.dtype != np.float32 or scales.shape != (coarse.shape[0], N_KEPT_SLICES):
            raise BasisError(f"{where}: 'factor_slice_scales' must be float32 of shape ({coarse.shape[0]}, "
                             f"{N_KEPT_SLICES}), got {scales.dtype} {scales.shape}")
        if not (np.isfinite(scales).all() and (scales > 0).all()):
            raise BasisError(f"{where}: 'factor_slice_scales' must be finite and positive")
        rows += coarse.shape[0]
    if factor_of.size and factor_of.max() >= rows:
        raise BasisError(f"{where}: 'factor_of' must name factor rows (0 to {rows - 1})")
    return FactorisedBasis(factors, colours.astype(np.int64), factor_of.astype(np.int64),
                           colour_entries.astype(np.int64), coarse, scales)

def basis_offset(linear_rank: int, basis_count: int, k: int) -> int:
    """The first basis vector an encoder uses for k coefficients.

    A decoder with a linear path over the first ``linear_rank`` principal
    components (``ModelConfig.linear_basis``: the latent's own) already
    spans the shared basis' leading vectors, which are the same components,
    so coefficients buy more on the vectors after them: on materials the
    model was not trained on, skipping those vectors lowers the error at small
    and medium counts and matches it at the largest (documentation: Layers and
    rate control). The offset shrinks where k would run past the basis' end.
    """
    return max(0, min(linear_rank, basis_count - k))

@functools.cache
def linear_path_entries() -> npt.NDArray[np.int64]:
    """Flat positions, in the ``(63, 90, 90)`` layout, of the entries a ``linear_basis`` decoder's linear path
    covers: those above the horizon (``spec/model.md`` §1), in increasing order (read-only)."""
    from brdfcodec.representation.layout import to_network_layout
    from brdfcodec.representation.mask import kept_slice_horizon_mask

    mask = to_network_layout(kept_slice_horizon_mask()[None].repeat(3, axis=0))
    entries = np.flatnonzero(mask.reshape(-1)).astype(np.int64)
    entries.setflags(write=False)
    return entries
