"""Consecutive vectors of a shared basis as a linear map for the encoder's fits, taken on the factors of a
factorised basis (``spec/model.md`` §5) rather than on its dense vectors.

The encoder fits basis coefficients again and again (least squares, Adam, the integer polish). On a dense
basis file the vectors are the rows of the stored matrix. On a factorised one each vector is a colour vector
times a factor row, and several vectors share a factor: the sums ``Σᵢ cᵢ vᵢ`` and the dot products ``r · vᵢ``
are taken as a small mixing matrix (vectors to factors and colours) and a product with the factors, which
take a fraction of the dense vectors' memory (F factor rows of one colour's entries against K vectors of all
three colours), and the dense vectors are never built.
"""

from __future__ import annotations

import warnings

import numpy as np
import numpy.typing as npt
import torch

from brdfcodec.conventions import N_CHANNELS
from brdfcodec.layers.basis import SharedBasis
from brdfcodec.layers.colour_orders_pca import COLOUR_VECTORS

__all__ = ["BasisOperator"]


def _read_only_tensor(values: npt.ArrayLike, device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """A tensor the fit only reads: the array's own memory when it is C-contiguous float32 on the CPU.

    Basis vectors and factors are large, read-only and cached (over 100 MB for the shipped basis); copying them
    for every fit doubled their memory at large budgets. Nothing writes to them (they hold no gradient), so
    torch may use them in place.
    """
    array = np.asarray(values)
    if array.dtype == np.float32 and device.type == "cpu" and dtype == torch.float32 and array.flags.c_contiguous:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="The given NumPy array is not writable")
            return torch.from_numpy(array)
    return torch.as_tensor(np.array(array, dtype=np.float32), device=device, dtype=dtype)


class BasisOperator:
    """The vectors ``first … first + k − 1`` of a shared basis, over its entries E, as a linear map.

    Build one with :meth:`of` (a model's basis: factorised where the file is) or :meth:`from_vectors` (a dense
    ``(k, E)`` array). :meth:`synthesise` and :meth:`analyse` take torch tensors (autograd flows through them),
    :meth:`row` and :meth:`combine` NumPy arrays.

    Attributes
    ----------
    count : int
        k, the vectors the map spans.
    """

    def __init__(self, count: int, dense: npt.NDArray[np.float32] | None,
                 factors: npt.NDArray[np.float32] | None, mixing: npt.NDArray[np.float32] | None,
                 basis: SharedBasis | None = None, first: int = 0) -> None:
        self.count = count
        self._dense = dense
        self._factors = factors
        self._mixing = mixing  # (k, F' · 3): vector i → its factor row's three colour weights
        self._basis, self._first = basis, first
        self._tensors: dict[tuple[torch.device, torch.dtype], tuple[torch.Tensor, torch.Tensor | None]] = {}

    @classmethod
    def of(cls, basis: SharedBasis, first: int, k: int) -> BasisOperator:
        """Vectors ``first … first + k − 1`` of ``basis``; a factorised basis keeps its factors (a view of the
        ones its vectors use, no copy).

        Raises
        ------
        BasisError
            Those vectors do not all exist.
        """
        basis.check_vectors(first, k)
        factorised = basis.factorised
        if factorised is None:
            return cls.from_vectors(basis.vectors(first, k), basis, first)
        rows = slice(first, first + k)
        factor_of = factorised.factor_of[rows]
        low, high = int(factor_of.min()), int(factor_of.max()) + 1
        factors = factorised.factors32[low:high]  # a view: unused rows in between get zero weights
        mixing = np.zeros((k, high - low, N_CHANNELS), dtype=np.float32)
        mixing[np.arange(k), factor_of - low] = COLOUR_VECTORS.astype(np.float32)[factorised.colours[rows]]
        return cls(k, None, factors, mixing.reshape(k, -1), basis, first)

    @classmethod
    def from_vectors(cls, vectors: npt.ArrayLike, basis: SharedBasis | None = None, first: int = 0) -> BasisOperator:
        """A dense ``(k, E)`` array of vectors (kept as it is when it is float32)."""
        dense = np.asarray(vectors)
        if dense.dtype != np.float32:
            dense = dense.astype(np.float32)
        if dense.ndim != 2:
            raise ValueError(f"basis vectors must be a (k, E) array, got shape {dense.shape}")
        return cls(len(dense), dense, None, None, basis, first)

    def _on(self, device: torch.device, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor | None]:
        key = (device, dtype)
        if key not in self._tensors:
            if self._dense is not None:
                self._tensors[key] = (_read_only_tensor(self._dense, device, dtype), None)
            else:
                assert self._factors is not None and self._mixing is not None
                self._tensors[key] = (_read_only_tensor(self._factors, device, dtype),
                                      torch.as_tensor(self._mixing, device=device, dtype=dtype))
        return self._tensors[key]

    def synthesise(self, coefficients: torch.Tensor) -> torch.Tensor:
        """``Σᵢ cᵢ vᵢ`` per row: coefficients ``(B, k)`` → values over the entries ``(B, E)``."""
        matrix, mixing = self._on(coefficients.device, coefficients.dtype)
        if mixing is None:
            return coefficients @ matrix
        folded = (coefficients @ mixing).reshape(len(coefficients), -1, N_CHANNELS).transpose(1, 2)  # (B, 3, F')
        return (folded @ matrix).reshape(len(coefficients), -1)

    def analyse(self, values: torch.Tensor) -> torch.Tensor:
        """``r · vᵢ`` per row: values over the entries ``(B, E)`` → dot products ``(B, k)``."""
        matrix, mixing = self._on(values.device, values.dtype)
        if mixing is None:
            return values @ matrix.T
        per_factor = values.reshape(len(values), N_CHANNELS, -1) @ matrix.T  # (B, 3, F')
        return per_factor.transpose(1, 2).reshape(len(values), -1) @ mixing.T

    def row(self, i: int) -> npt.NDArray[np.float32]:
        """Vector ``first + i`` over the entries, ``(E,)`` float32 (NumPy)."""
        if self._dense is not None:
            return self._dense[i]
        assert self._basis is not None and self._basis.factorised is not None
        return self._basis.factorised.products(self._first + i, 1)[0]

    def combine(self, coefficients: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """``Σᵢ cᵢ vᵢ`` over the entries, ``(E,)`` float32 (NumPy; on the factors where the basis has them)."""
        c = np.asarray(coefficients, dtype=np.float32).reshape(-1)
        if self._dense is not None:
            return c @ self._dense
        assert self._basis is not None
        return self._basis.weighted_sum(c, self._first)
