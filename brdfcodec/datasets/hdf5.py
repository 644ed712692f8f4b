"""HDF5 datasets of network inputs, masks and full tables (``spec/dataset-format.md``).

A dataset file holds, for N materials: the β-VAE inputs (21 kept φd slices,
log-mapped, in the 63×90×90 network layout), their validity masks, the full
tables (float32 copies in stored MERL units, for metrics), the names, where
each material came from, and a deterministic train/validation split.
"""

from __future__ import annotations

import datetime
import os
from collections import deque
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from types import TracebackType
from typing import Final

import h5py
import numpy as np
import numpy.typing as npt
from tqdm.auto import tqdm

from brdfcodec.conventions import (
    CONVENTIONS_VERSION,
    EPSILON,
    KEPT_PHI_D_SLICES,
    MERL_COLOR_SCALE,
    NETWORK_INPUT_SHAPE,
    TABLE_SHAPE,
    UNMEASURED_VALUE,
)
from brdfcodec.datasets.sources import LoadedMaterial, MaterialSource
from brdfcodec.datasets.split import TRAIN, VALIDATION, split_by_family
from brdfcodec.errors import DatasetError
from brdfcodec.io.atomic import atomic_output
from brdfcodec.io.hashing import is_sha256_hex
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.io.rgl import RGL_SOURCE_KIND
from brdfcodec.representation import network_input_from_table
from brdfcodec.version import __version__

__all__ = [
    "DATASET_FORMAT",
    "DATASET_FORMAT_VERSION",
    "HDF5_SIGNATURE",
    "MIXED_SOURCE_KIND",
    "BrdfDataset",
    "build_dataset",
    "material_arrays",
]

#: Value of the root attribute ``format``.
DATASET_FORMAT: Final = "brdfcodec-dataset"
#: Value of the root attribute ``format_version`` written by this code.
DATASET_FORMAT_VERSION: Final = 1
#: First bytes of every HDF5 file, hence of every dataset file (how ``bvae info`` and ``bvae compress`` tell one).
HDF5_SIGNATURE: Final = b"\x89HDF\r\n\x1a\n"

#: Root ``source_kind`` of a dataset whose materials come from sources of different kinds.
MIXED_SOURCE_KIND: Final = "mixed"
# Family of every material of a dataset written before per-material families existed.
_LEGACY_FAMILIES: Final = {"merl": "merl", "nbrdf-proxy": "merl", "analytic": "analytic"}

_STRING = h5py.string_dtype("utf-8")
_COMPRESSION: Final = {"compression": "gzip", "compression_opts": 1, "shuffle": True}


def material_arrays(brdf: MerlBRDF) -> tuple[np.ndarray, np.ndarray]:
    """Network input and its mask for one table: :func:`brdfcodec.representation.network_input_from_table`.

    Returns
    -------
    inputs : ndarray of float32, shape (63, 90, 90)
        Log-mapped kept slices; invalid entries are 0.
    mask : ndarray of bool, shape (63, 90, 90)
        Valid entries.
    """
    return network_input_from_table(brdf.values, brdf.mask)


def build_dataset(
    output: str | os.PathLike[str],
    sources: Sequence[MaterialSource],
    *,
    description: str,
    source_kind: str | None = None,
    validation_fraction: float = 0.15,
    seed: int = 0,
    include_tables: bool = True,
    overwrite: bool = False,
    progress: bool = True,
    jobs: int = 1,
) -> Path:
    """Write a dataset file from material sources, atomically.

    Parameters
    ----------
    output : str or os.PathLike
        The ``.h5`` file to create.
    sources : sequence of MaterialSource
        Materials, each loaded once (see :mod:`brdfcodec.datasets.sources`).
    description : str
        One sentence naming the data, stored as the ``description`` attribute.
    source_kind : str, optional
        The root ``source_kind`` attribute; by default the sources' common
        kind (``"merl"``, ``"rgl-measured"``, ``"nbrdf-proxy"``,
        ``"analytic"``), or ``"mixed"`` when they differ. Each material's
        own kind and family are stored too, so no one mistakes a proxy for
        measurements.
    validation_fraction : float, default 0.15
        Share of each family held out for validation (see
        :func:`brdfcodec.datasets.split.split_by_family`).
    seed : int, default 0
        Seed of the split.
    include_tables : bool, default True
        Also store full 90×90×180 tables (float32, compressed), needed to measure RelAE on the full table.
    overwrite : bool, default False
        Replace an existing file.
    progress : bool, default True
        Show a progress bar on stderr.
    jobs : int, default 1
        Materials loaded (read or tabulated, then mapped to network inputs) at once, on threads (at most as
        many as the machine has cores); the file is
        written on the calling thread in the sources' order, so that its content does not depend on ``jobs``.
        RGL measurements, tabulated through Mitsuba, are loaded on the calling thread whatever ``jobs`` is.

    Returns
    -------
    pathlib.Path
        The written file. On any error nothing is left at ``output``.
    """
    if not sources:
        raise ValueError("no materials to write")
    if jobs < 1:
        raise ValueError(f"jobs must be at least 1, got {jobs}")
    names = [source.name for source in sources]
    _check_distinct(sources)
    families = [source.family for source in sources]
    kinds = [source.source_kind for source in sources]
    if source_kind is None:
        source_kind = kinds[0] if len(set(kinds)) == 1 else MIXED_SOURCE_KIND
    split = split_by_family(names, families, validation_fraction=validation_fraction, seed=seed)
    n = len(sources)
    with atomic_output(output, overwrite=overwrite) as tmp, h5py.File(tmp, "w") as handle:
        attrs = handle.attrs
        attrs["format"] = DATASET_FORMAT
        attrs["format_version"] = DATASET_FORMAT_VERSION
        attrs["conventions_version"] = CONVENTIONS_VERSION
        attrs["source_kind"] = source_kind
        attrs["description"] = description
        attrs["brdfcodec_version"] = __version__
        attrs["created"] = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
        attrs["validation_fraction"] = validation_fraction
        attrs["split_seed"] = seed
        attrs["kept_phi_d_slices"] = np.asarray(KEPT_PHI_D_SLICES, dtype=np.int16)
        attrs["color_scale"] = MERL_COLOR_SCALE
        attrs["epsilon"] = EPSILON
        handle.create_dataset("names", data=names, dtype=_STRING)
        handle.create_dataset("split", data=split, dtype=_STRING)
        handle.create_dataset("origins", data=[s.origin for s in sources], dtype=_STRING)
        handle.create_dataset("families", data=families, dtype=_STRING)
        handle.create_dataset("source_kinds", data=kinds, dtype=_STRING)
        digests = handle.create_dataset("source_sha256", shape=(n,), dtype=_STRING)
        genuine = handle.create_dataset("genuine_merl", shape=(n,), dtype=_STRING)
        inputs = handle.create_dataset(
            "inputs", shape=(n, *NETWORK_INPUT_SHAPE), dtype=np.float32,
            chunks=(1, *NETWORK_INPUT_SHAPE), **_COMPRESSION,
        )
        masks = handle.create_dataset(
            "input_masks", shape=(n, *NETWORK_INPUT_SHAPE), dtype=bool,
            chunks=(1, *NETWORK_INPUT_SHAPE), **_COMPRESSION,
        )
        tables = None
        if include_tables:
            tables = handle.create_dataset(
                "tables", shape=(n, *TABLE_SHAPE), dtype=np.float32,
                chunks=(1, 1, *TABLE_SHAPE[1:]), **_COMPRESSION,
            )
        bar = tqdm(total=n, desc="materials", unit="mat", disable=not progress)
        for index, (loaded, network_input, mask) in enumerate(_loaded_in_order(sources, jobs)):
            inputs[index], masks[index] = network_input, mask
            digests[index] = loaded.source_sha256
            genuine[index] = loaded.genuine_merl
            if tables is not None:
                tables[index] = np.where(loaded.brdf.mask, loaded.brdf.values, UNMEASURED_VALUE)
            bar.update()
        bar.close()
    return Path(output)


def _load_one(source: MaterialSource) -> tuple[LoadedMaterial, np.ndarray, np.ndarray]:
    loaded = source.load()
    return (loaded, *network_input_from_table(loaded.brdf.values, loaded.brdf.mask))


def _loaded_in_order(
    sources: Sequence[MaterialSource], jobs: int
) -> Iterator[tuple[LoadedMaterial, np.ndarray, np.ndarray]]:
    """Each source loaded with its network input and mask, in order; up to ``jobs`` loading at once (at most
    2 · ``jobs`` materials held in memory ahead of the writer). A load's error is raised in the sources' order, and
    the loads not yet started are cancelled."""
    if jobs == 1:
        yield from map(_load_one, sources)
        return
    jobs = min(jobs, os.cpu_count() or 1)  # more threads than cores only hold more materials in memory
    pending: deque[Future[tuple[LoadedMaterial, np.ndarray, np.ndarray]] | MaterialSource] = deque()
    upcoming = iter(sources)
    executor = ThreadPoolExecutor(max_workers=jobs, thread_name_prefix="brdfcodec-dataset")
    try:
        while True:
            while len(pending) < 2 * jobs and (source := next(upcoming, None)) is not None:
                # Mitsuba (RGL measurements) is not asked to load on several threads: those load in turn, here.
                pending.append(source if source.source_kind == RGL_SOURCE_KIND else executor.submit(_load_one, source))
            if not pending:
                return
            head = pending.popleft()
            yield _load_one(head) if isinstance(head, MaterialSource) else head.result()
    finally:
        executor.shutdown(wait=True, cancel_futures=True)


def _check_distinct(sources: Sequence[MaterialSource]) -> None:
    seen: dict[str, str] = {}
    for source in sources:
        if source.name in seen:
            raise ValueError(
                f"two sources give the material name {source.name!r}: {seen[source.name]} and {source.origin}"
            )
        seen[source.name] = source.origin


class BrdfDataset:
    """Read-only view of a dataset file; use as a context manager.

    Parameters
    ----------
    path : str or os.PathLike
        A file written by :func:`build_dataset`.

    Raises
    ------
    DatasetError
        Not a brdfcodec dataset, an unsupported version, or inconsistent shapes.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        if self.path.is_dir():
            raise IsADirectoryError(f"{self.path}: is a directory, expected a dataset .h5 file")
        if not self.path.exists():
            raise FileNotFoundError(f"{self.path}: no such dataset file")
        try:
            self._handle = h5py.File(self.path, "r")
        except OSError as error:
            raise DatasetError(self.path, f"not an HDF5 file ({error})") from None
        try:
            self._validate()
        except BaseException:
            self._handle.close()
            raise
        self.names: list[str] = self._strings("names")
        self.split: list[str] = self._strings("split")
        kind = str(self._handle.attrs["source_kind"])
        #: Each material's measurement family (``"merl"``, ``"rgl"``, ``"analytic"``, ...).
        self.families: list[str] = (
            self._strings("families") if "families" in self._handle else [_LEGACY_FAMILIES.get(kind, kind)] * len(self)
        )
        #: Each material's source kind (``"merl"``, ``"rgl-measured"``, ``"nbrdf-proxy"``, ``"analytic"``).
        self.source_kinds: list[str] = (
            self._strings("source_kinds") if "source_kinds" in self._handle else [kind] * len(self)
        )

    def _strings(self, key: str) -> list[str]:
        return [s.decode() if isinstance(s, bytes) else str(s) for s in self._handle[key][()]]

    def _validate(self) -> None:
        attrs = self._handle.attrs
        if attrs.get("format") != DATASET_FORMAT:
            raise DatasetError(self.path, f"not a brdfcodec dataset (format attribute {attrs.get('format')!r})")
        version = int(attrs.get("format_version", -1))
        if version != DATASET_FORMAT_VERSION:
            raise DatasetError(
                self.path,
                f"dataset format version {version}, this brdfcodec reads {DATASET_FORMAT_VERSION}; "
                "rebuild it with `bvae dataset build`",
            )
        missing = [k for k in ("names", "split", "inputs", "input_masks") if k not in self._handle]
        if missing:
            raise DatasetError(self.path, f"dataset lacks {', '.join(missing)}")
        n = self._handle["names"].shape[0]
        expected = {"split": (n,), "inputs": (n, *NETWORK_INPUT_SHAPE), "input_masks": (n, *NETWORK_INPUT_SHAPE)}
        if "tables" in self._handle:
            expected["tables"] = (n, *TABLE_SHAPE)
        for optional in ("families", "source_kinds"):
            if optional in self._handle:
                expected[optional] = (n,)
        for key, shape in expected.items():
            if self._handle[key].shape != shape:
                raise DatasetError(self.path, f"{key} has shape {self._handle[key].shape}, expected {shape}")

    def __enter__(self) -> BrdfDataset:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def close(self) -> None:
        """Close the file."""
        self._handle.close()

    def __len__(self) -> int:
        return len(self.names)

    @property
    def source_kind(self) -> str:
        """``"merl"``, ``"rgl-measured"``, ``"nbrdf-proxy"``, ``"analytic"``, or ``"mixed"`` (see ``source_kinds``)."""
        return str(self._handle.attrs["source_kind"])

    @property
    def description(self) -> str:
        """One sentence naming the data."""
        return str(self._handle.attrs["description"])

    @property
    def has_tables(self) -> bool:
        """Whether full tables are stored."""
        return "tables" in self._handle

    def attribute(self, key: str) -> object:
        """A root attribute of the file (``created``, ``split_seed``, ...)."""
        return self._handle.attrs[key]

    def indices(self, split: str | None = None, *, family: str | None = None) -> list[int]:
        """Material indices of one split (``"train"`` or ``"validation"``) and/or one family; all by default."""
        if split is not None and split not in (TRAIN, VALIDATION):
            raise ValueError(f"split must be {TRAIN!r} or {VALIDATION!r}, got {split!r}")
        if family is not None and family not in self.families:
            raise ValueError(f"{self.path}: no family {family!r}; it has {sorted(set(self.families))}")
        return [
            i
            for i in range(len(self))
            if (split is None or self.split[i] == split) and (family is None or self.families[i] == family)
        ]

    def index_of(self, name: str) -> int:
        """Index of a material by name."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"{self.path}: no material named {name!r}") from None

    def inputs(self, indices: Sequence[int] | None = None) -> npt.NDArray[np.float32]:
        """Network inputs, shape (len(indices), 63, 90, 90); all materials by default."""
        return self._rows("inputs", indices)

    def input_masks(self, indices: Sequence[int] | None = None) -> npt.NDArray[np.bool_]:
        """Validity masks of the inputs, shape (len(indices), 63, 90, 90)."""
        return self._rows("input_masks", indices)

    def table(self, index: int) -> MerlBRDF:
        """Full table of one material, as float64 stored values, with its provenance.

        ``source_sha256`` is the source's (as recorded when the dataset was
        built), and ``source_kind`` is ``"rgl-measured"`` for a table
        tabulated from an RGL measurement, as :func:`brdfcodec.io.rgl.read_rgl_bsdf`
        gives it, so that records encoded from a dataset row carry the same
        metadata as records encoded from the source file (``spec/bvae-format.md`` §5).

        Raises
        ------
        DatasetError
            The dataset was built without tables.
        """
        if not self.has_tables:
            raise DatasetError(self.path, "dataset was built without full tables (--no-tables)")
        values = np.asarray(self._handle["tables"][index], dtype=np.float64)
        digest = None
        if "source_sha256" in self._handle:
            stored = self._handle["source_sha256"][index]
            text = stored.decode() if isinstance(stored, bytes) else str(stored)
            digest = text if is_sha256_hex(text) else None  # a hand-made dataset may hold anything
        kind = RGL_SOURCE_KIND if self.source_kinds[index] == RGL_SOURCE_KIND else None
        return MerlBRDF(values, name=self.names[index], source_kind=kind, source_sha256=digest)

    def _rows(self, key: str, indices: Sequence[int] | None) -> np.ndarray:
        data = self._handle[key]
        if indices is None:
            return data[()]
        order = np.asarray(indices, dtype=np.intp)
        if order.size == 0:
            return np.empty((0, *data.shape[1:]), dtype=data.dtype)
        unique, inverse = np.unique(order, return_inverse=True)  # h5py wants increasing indices
        return data[unique.tolist()][inverse]
