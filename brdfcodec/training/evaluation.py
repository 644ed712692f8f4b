"""Per-material mapped RelAE of a model's reconstructions on the full 90×90×180 table, while it trains."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
import torch

from brdfcodec.datasets.hdf5 import BrdfDataset
from brdfcodec.errors import DatasetError
from brdfcodec.models.network import BetaVAE
from brdfcodec.representation import from_network_layout, interpolate_slices, map_values
from brdfcodec.representation.metrics import relae_between_mapped

__all__ = ["MappedReference", "reconstruct_mapped"]


class MappedReference:
    """Mapped full tables and masks of some materials, cached for repeated evaluation.

    The mapped RelAE of ``spec/conventions.md`` §8 compares mapped values;
    since the inverse mapping is exact on [0, MAPPED_MAX], a decoder's mapped
    output, interpolated to 180 slices, is compared directly with the mapped
    reference (:func:`~brdfcodec.representation.metrics.relae_between_mapped`, no round trip
    through stored units).

    Parameters
    ----------
    dataset : BrdfDataset
        With full tables.
    indices : sequence of int
        Materials to cache (about 22 MB each).
    """

    def __init__(self, dataset: BrdfDataset, indices: Sequence[int]) -> None:
        if not dataset.has_tables:
            raise DatasetError(dataset.path, "evaluation needs full tables; rebuild the dataset without --no-tables")
        self.indices = list(indices)
        self.names = [dataset.names[i] for i in self.indices]
        self._mapped: list[np.ndarray] = []
        self._masks: list[np.ndarray] = []
        for index in self.indices:
            table = dataset.table(index)
            self._masks.append(table.mask)
            self._mapped.append(np.where(table.mask, map_values(table.values), 0.0).astype(np.float32))

    def relae(self, outputs: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Mapped RelAE (overall) of each material.

        Parameters
        ----------
        outputs : array_like, shape (n, 63, 90, 90)
            Mapped network outputs, in the order of ``indices``.
        """
        outputs = np.asarray(outputs, dtype=np.float32)
        errors = np.empty(len(self.indices))
        for k, (reference, mask) in enumerate(zip(self._mapped, self._masks, strict=True)):
            full = interpolate_slices(from_network_layout(outputs[k]))
            errors[k] = relae_between_mapped(reference, full, mask).overall
        return errors


def reconstruct_mapped(
    model: BetaVAE, inputs: npt.ArrayLike, *, device: torch.device | str = "cpu", batch_size: int = 16
) -> npt.NDArray[np.float32]:
    """Mapped reconstructions ``decoder(μ(x))`` in evaluation mode, shape (n, 63, 90, 90).

    Runs through :class:`~brdfcodec.codec.BrdfEncoder` and
    :class:`~brdfcodec.codec.BrdfDecoder`, as a shipped model decodes.
    """
    from brdfcodec.codec import BrdfDecoder, BrdfEncoder

    array = np.asarray(inputs, dtype=np.float32)
    if not len(array):
        return np.empty((0, *array.shape[1:]), np.float32)
    mu, _ = BrdfEncoder.from_network(model.encoder, device=device).posterior_from_inputs(array, batch_size=batch_size)
    return BrdfDecoder.from_network(model.decoder, device=device).decode_mapped(mu, batch_size=batch_size)
