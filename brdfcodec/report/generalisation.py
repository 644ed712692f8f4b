"""Rate–distortion on held-out materials, in file bytes: brdfcodec against PCA fitted on the same materials.

The question a user asks of a codec: *at N bytes per material, on materials
the model never saw, which codec is better?* One :class:`Experiment` is a
model folder and the materials it held out (by default those its
``model.json`` lists as not trained on: a cross-validation fold, or a whole
family never seen). For each size budget N and each family of the held-out
materials, :func:`run_experiment` measures

- ``bvae``: the held-out materials (of every family, limited per family)
  encoded into one library with ``bvae compress --bytes N'`` (effort 1, float16 latents, no
  provenance, ``--latent auto`` unless the experiment says ``"latent":
  "always"``) through the public API, where N' ≤ N leaves room for the
  materials' share of the file's header (``bytes_flag`` in the rows): the
  **file's** bytes less the materials' names (UTF-8), divided by the number
  of materials, is at most N; a family's bytes per material are its
  records' (descriptor and payload, names aside) plus an equal share of the
  header per material, and N' is the largest value found (from an estimate
  of the header's share, then up or down by the bytes per material to spare
  or in excess) for which every family's are at most N too (a family whose
  records fill their budget while another's do not would otherwise exceed N
  by a fraction of the header's share);
- ``pca-*``: PCA of the mapped kept slices fitted on the *same training
  materials* as the model (as measured, ``pca``, and in all six colour
  orders, ``pca-perm``), with k coefficients as int8 plus one float16 scale
  (k + 2 bytes) or as float16 (2k bytes), k chosen to fill N bytes (at most
  the basis' rank). No container, index or name is counted for PCA: the
  comparison favours it;
- ``pca-tc``, ``pca-perm-tc``: the same bases (all the components the training
  materials support) **transform-coded**: bits per coefficient by reverse
  water-filling on the training coefficients' variances, uniform quantisers,
  one gain byte per material, exactly N bytes; ``pca-ec-laplace``,
  ``pca-ec-gaussian`` (and ``pca-perm-…``): **entropy-coded**, one step per
  material (a byte) and the coefficients range-coded under priors of the
  training spread, at most N bytes counted from the coder's output
  (:mod:`brdfcodec.report.pca_coding`, issue 48);
- with ``"pca_edge_slots": true``, each of those also as ``pca-edge``, ``pca-perm-edge`` (and their coded
  variants): the bases fitted on the training materials' kept slices with their edge slots filled
  (:func:`~brdfcodec.representation.edge_slots.edge_slot_targets`: the slots below the horizon that the
  interpolation carries into valid bins, at the values that fit those bins best), each held-out material's
  filled the same way before it is coded: the PCA baselines given what ``bvae train --edge-slots`` gives a
  model.

Errors are the mean mapped and linear RelAE on the full table over valid
entries (``spec/conventions.md``). Every point's row also carries its decode
time per material (``decode_ms_median``, ``decode_ms_mean``: brdfcodec from
the library's record to the full table, PCA from the stored coefficients or
payload to the full table, one process, after a warm-up decode) and the
machine it was measured on (``decode_machine``). Every row carries the commit, the model's
decoder hash and the data it came from (:mod:`brdfcodec.report.rows`).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from brdfcodec.codec.library_budget import header_estimate
from brdfcodec.errors import RateTargetError
from brdfcodec.layers.coded_basis import MAX_MU_STEP_LOG2

__all__ = ["DEFAULT_BUDGETS", "Experiment", "RdConfig", "decode_machine", "load_config", "run_config",
           "run_experiment"]

#: The smallest record brdfcodec writes, its descriptor included (a record without a latent, one coefficient).
_SMALLEST_RECORD = 6
#: Size budgets of the comparison, bytes per material.
DEFAULT_BUDGETS = (16, 32, 64, 128)


@dataclass(frozen=True)
class Experiment:
    """A model and the materials it is measured on.

    Attributes
    ----------
    label : str
        Names the experiment in the rows (``"cv3-fold0"``, ``"never-seen-rgl"``).
    model : pathlib.Path
        Model folder (``bvae model export``).
    group : str
        Rows of experiments in one group are pooled in the summary (the
        folds of one cross-validation); by default the label.
    held_out : tuple of str, optional
        Material names to measure on; by default every dataset material the
        model's ``model.json`` does not list as trained on.
    latent : {"auto", "always"}
        Whether rate control may write records without a latent (format 2.1; ``bvae compress --latent``).
    coded_mu_step : int or tuple of int, optional
        The grid exponents of rate control's coded-μ candidates: one, 0 (none) to
        :data:`~brdfcodec.layers.coded_basis.MAX_MU_STEP_LOG2`, or several, each a pool of candidates
        (``BrdfEncoder(coded_mu_step=)``); the encoder's default when None.
    short_references : bool, default True
        Whether the library names its decoder and basis by short references (format 2.6,
        ``brdfcodec.encode(short_references=)``), the encoder's default; False writes full hashes, 48 bytes more a
        file, as files before 2.6 did.
    allocate : {"record", "library"}, default "record"
        How the budget is spent (``bvae compress --allocate``): ``"record"`` searches the largest ``--bytes`` whose
        library fits N per material; ``"library"`` encodes once with ``--bytes N --allocate library``, each family
        its own group, so that every family's records and share of the header fit N per material.
    """

    label: str
    model: Path
    group: str = ""
    held_out: tuple[str, ...] | None = None
    latent: str = "auto"
    coded_mu_step: int | tuple[int, ...] | None = None
    short_references: bool = True
    allocate: str = "record"


@dataclass(frozen=True)
class RdConfig:
    """What :func:`run_config` measures (the JSON file of ``bvae bench rd --config``)."""

    dataset: Path
    experiments: tuple[Experiment, ...]
    budgets: tuple[int, ...] = DEFAULT_BUDGETS
    effort: int = 1
    limit: int | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    header_in_budget: bool = True
    pca_edge_slots: bool = False


def load_config(path: str | os.PathLike[str]) -> RdConfig:
    """Read a runner configuration; relative paths are taken from the file's folder.

    The file is a JSON object: ``dataset`` (path), ``experiments`` (list of
    objects with ``label``, ``model``, optional ``group``, ``held_out``,
    ``latent``: ``"auto"``, the default, or ``"always"``, as ``bvae compress --latent``, and
    ``coded_mu_step``: 0 to 5, the coded-μ candidates' grid exponent, or a list of grids, a study of the
    encoder's default, and
    ``short_references``: true, the default, or false, full hashes in the header as before format 2.6, and
    ``allocate``: ``"record"``, the default, or ``"library"``, as ``bvae compress --allocate``),
    optional ``budgets`` (list of int), ``effort`` (int), ``limit`` (int:
    only the first N held-out materials of each family, a quick look),
    ``header_in_budget`` (bool, default true: brdfcodec's file bytes less
    the names stay within N per material, its share of the header
    included; false: ``--bytes N`` as given, the header on top — the curve
    of a single-material file, whose header alone exceeds the small budgets),
    ``pca_edge_slots`` (bool, default false: also the PCA baselines with edge
    slots, the module's ``pca-edge`` points).

    Raises
    ------
    ValueError
        A missing or unknown key, or a value of the wrong type.
    """
    base = Path(path).parent
    data = json.loads(Path(path).read_text(encoding="utf-8"))
    known = {"dataset", "experiments", "budgets", "effort", "limit", "description", "header_in_budget",
             "pca_edge_slots"}
    if not isinstance(data, dict) or "dataset" not in data or "experiments" not in data:
        raise ValueError(f"{path}: a runner configuration is an object with 'dataset' and 'experiments'")
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"{path}: unknown keys {unknown}")
    experiments = []
    for item in data["experiments"]:
        if not isinstance(item, dict) or not {"label", "model"} <= set(item) or set(item) - {
                "label", "model", "group", "held_out", "latent", "coded_mu_step", "short_references", "allocate"}:
            raise ValueError(f"{path}: each experiment is an object with 'label', 'model' (and optionally "
                             f"'group', 'held_out', 'latent', 'coded_mu_step', 'short_references', 'allocate'), "
                             f"got {item!r}")
        if item.get("allocate", "record") not in ("record", "library"):
            raise ValueError(f"{path}: an experiment's 'allocate' is 'record' or 'library', got {item['allocate']!r}")
        if not isinstance(item.get("short_references", True), bool):
            raise ValueError(f"{path}: an experiment's 'short_references' is true or false, "
                             f"got {item['short_references']!r}")
        if item.get("latent", "auto") not in ("auto", "always"):
            raise ValueError(f"{path}: an experiment's 'latent' is 'auto' or 'always', got {item['latent']!r}")
        step = item.get("coded_mu_step")
        if isinstance(step, list):
            from brdfcodec.codec.rate import coded_mu_grids

            try:
                step = coded_mu_grids(step) or None  # an empty list: refused below
            except ValueError:
                step = None
            if step is None:
                raise ValueError(f"{path}: an experiment's 'coded_mu_step' list holds distinct integers from 1 to "
                                 f"{MAX_MU_STEP_LOG2}, got {item['coded_mu_step']!r}")
        elif step is not None and (isinstance(step, bool) or not isinstance(step, int) or
                                   not 0 <= step <= MAX_MU_STEP_LOG2):
            raise ValueError(f"{path}: an experiment's 'coded_mu_step' is an integer from 0 to {MAX_MU_STEP_LOG2}, "
                             f"or a list of grids, got {step!r}")
        held = item.get("held_out")
        experiments.append(Experiment(str(item["label"]), base / item["model"], str(item.get("group", "")),
                                      None if held is None else tuple(str(n) for n in held),
                                      str(item.get("latent", "auto")), step, item.get("short_references", True),
                                      str(item.get("allocate", "record"))))
    budgets = tuple(int(n) for n in data.get("budgets", DEFAULT_BUDGETS))
    if not budgets or min(budgets) < 1:
        raise ValueError(f"{path}: budgets must be positive integers")
    limit = data.get("limit")
    header_in_budget = data.get("header_in_budget", True)
    if not isinstance(header_in_budget, bool):
        raise ValueError(f"{path}: 'header_in_budget' is true or false, got {header_in_budget!r}")
    pca_edge_slots = data.get("pca_edge_slots", False)
    if not isinstance(pca_edge_slots, bool):
        raise ValueError(f"{path}: 'pca_edge_slots' is true or false, got {pca_edge_slots!r}")
    return RdConfig(base / data["dataset"], tuple(experiments), budgets, int(data.get("effort", 1)),
                    None if limit is None else int(limit), {"description": data.get("description", "")},
                    header_in_budget, pca_edge_slots)


def _pca_payload_counts(budget: int, rank: int) -> dict[str, int]:
    """Coefficients that fill ``budget`` bytes: int8 with a float16 scale, or float16 (capped at the rank)."""
    counts = {}
    if budget - 2 >= 1:
        counts["int8"] = min(budget - 2, rank)
    if budget // 2 >= 1:
        counts["float16"] = min(budget // 2, rank)
    return counts


def _pack_pca(coefficients: np.ndarray, storage: str) -> np.ndarray:
    """Quantise PCA coefficients as stored (int8 with one float16 scale per material, or float16)."""
    if storage == "float16":
        return coefficients.astype(np.float16).astype(np.float32)
    scale = np.maximum(np.abs(coefficients).max(axis=1, keepdims=True), 1e-6) / 127.0
    scale = scale.astype(np.float16).astype(np.float32)
    return np.clip(np.rint(coefficients / scale), -127, 127) * scale


def _pca_rows(name: str, basis: Any, inputs: np.ndarray, references: Sequence[Any], budgets: Sequence[int],
              error: Callable[[Any, np.ndarray], tuple[float, float]]) -> list[dict[str, Any]]:
    from brdfcodec.conventions import MAPPED_MAX
    from brdfcodec.representation import table_from_network_output

    flat = inputs.reshape(len(inputs), -1) - basis.mean
    rows = []
    for budget in budgets:
        for storage, k in _pca_payload_counts(budget, basis.n_components).items():
            coefficients = _pack_pca(flat @ basis.components[:k].T, storage)
            errors, seconds = [], []
            for c, reference in zip(coefficients, references, strict=True):
                start = time.perf_counter()  # timed: the (dequantised) coefficients to the full table
                mapped = np.clip(c @ basis.components[:k] + basis.mean, 0.0, MAPPED_MAX).reshape(63, 90, 90)
                table = table_from_network_output(mapped)
                seconds.append(time.perf_counter() - start)
                errors.append(error(reference, table))
            payload = k + 2 if storage == "int8" else 2 * k
            rows.append({"point": f"{name}-{storage}", "budget_bytes": budget, "coefficients": k,
                         "bytes_per_material": float(payload), **_error_summary(errors), **_decode_time(seconds)})
    return rows


def _decode_time(seconds: Sequence[float]) -> dict[str, Any]:
    """Decode time per material (ms): median and mean, from the stored bytes to the full table."""
    return {"decode_ms_median": 1e3 * float(np.median(seconds)), "decode_ms_mean": 1e3 * float(np.mean(seconds))}


def decode_machine() -> str:
    """The machine decode times were measured on, in words (CPU model, cores, torch's thread count)."""
    import platform

    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as info:
            model = next((line.split(":", 1)[1].strip() for line in info if line.startswith("model name")), model)
    except OSError:
        pass
    try:
        import torch

        threads = f", torch {torch.get_num_threads()} threads"
    except ImportError:  # pragma: no cover - torch is a dependency of the decoder
        threads = ""
    return f"CPU: {model}, {os.cpu_count()} logical cores{threads}"


def _error_summary(errors: Sequence[tuple[float, float]]) -> dict[str, Any]:
    mapped = np.array([e[0] for e in errors])
    linear = np.array([e[1] for e in errors])
    return {"mapped_relae_mean": float(mapped.mean()), "mapped_relae_median": float(np.median(mapped)),
            "linear_relae_mean": float(linear.mean()), "per_material_mapped": [float(v) for v in mapped]}


def _record_bytes(library: Any, data: bytes, names: Sequence[str], name_bytes: int) -> tuple[dict[str, int], float]:
    """Each material's record bytes (descriptor and payload, its name aside) and the header's share per material
    (the file's bytes less the names and the records, divided by the number of materials)."""
    entries = {entry.name: entry for entry in library.header.entries}
    record_bytes = {n: entries[n].length + entries[n].descriptor_bytes for n in names}
    return record_bytes, (len(data) - name_bytes - sum(record_bytes.values())) / len(names)


def bytes_over_budget(record_bytes: dict[str, int], header_share: float, families: Sequence[str],
                      budget: int) -> float:
    """How far a library's bytes per material exceed the budget N: the most, over the file and each family, of
    its mean record bytes (descriptor and payload, names aside) plus the header's share per material, less N
    (≤ 0: within the budget).

    Parameters
    ----------
    record_bytes : dict of str to int
        Each material's record bytes, in the order of ``families``.
    header_share : float
        The file's bytes less the names and the records, per material.
    families : sequence of str
        Each material's family, in the order of ``record_bytes``.
    budget : int
        N, bytes per material.
    """
    sizes = np.array(list(record_bytes.values()), dtype=np.float64)
    labels = np.asarray(families)
    means = [sizes.mean(), *(sizes[labels == family].mean() for family in dict.fromkeys(families))]
    return float(max(means) + header_share - budget)


def search_bytes_flag(
    encoded: Callable[[int], tuple[Any, dict[str, int], float]], flag: int, budget: int, families: Sequence[str],
    *, tries: int = 8,
) -> tuple[int, Any, dict[str, int], float]:
    """The largest ``--bytes`` value for which a library's bytes per material, over the file and each family, stay
    within the budget N (:func:`bytes_over_budget`), searched from ``flag``.

    Each try encodes once. Over the budget, the flag is lowered by the excess (rounded up), never to one known to
    fit or below 1; within it with a byte or more per material to spare, it is raised by the spare (at most to
    N: the header's share may have been estimated high), unless the last larger flag made no larger records (the
    records are full). The search stops at a flag already tried, after ``tries`` encodes, or when no step is left.

    Parameters
    ----------
    encoded : callable
        ``encoded(flag)`` → ``(result, record_bytes, header_share)``: the library written with ``--bytes flag``
        (``result`` is handed back as it is), its materials' record bytes in the order of ``families``, and the
        header's share per material.
    flag : int
        The first ``--bytes`` to try (N less an estimate of the header's share).
    budget : int
        N, bytes per material.
    families : sequence of str
        Each material's family.
    tries : int, default 8
        Most encodes (1: ``flag`` only).

    Returns
    -------
    flag, result, record_bytes, header_share
        Of the largest flag tried that fits, else of the last one encoded.

    Raises
    ------
    RateTargetError
        ``encoded(flag)`` raised it for the first flag (a later flag that raises it ends the search).
    """
    fitting: tuple[int, Any, dict[str, int], float] | None = None  # the largest --bytes within N
    last: tuple[int, Any, dict[str, int], float] | None = None
    tried: set[int] = set()
    grown = True  # whether the last larger --bytes made larger records (else the records are full)
    for _ in range(max(1, tries)):
        try:
            result, record_bytes, header_share = encoded(flag)
        except RateTargetError:  # below the smallest record a material can take: no smaller flag fits either
            if last is None:
                raise
            break
        last = (flag, result, record_bytes, header_share)
        over = bytes_over_budget(record_bytes, header_share, families, budget)
        tried.add(flag)
        if over <= 0 and (fitting is None or flag > fitting[0]):
            if fitting is not None:
                grown = sum(record_bytes.values()) > sum(fitting[2].values())
            fitting = last
        # a byte or more per material to spare: a larger --bytes (at most N) may fit, the header's share
        # having been estimated high, unless the records stopped growing; over: a smaller one, down to the
        # largest known to fit
        step = min(math.floor(-over), budget - flag) if over <= 0 else -math.ceil(over)
        if tries <= 1 or step == 0 or flag + step in tried or flag + step < 1:
            break
        if step > 0 and not grown:
            break
        if fitting is not None and step < 0 and flag + step <= fitting[0]:
            break
        flag += step
    assert last is not None
    return fitting if fitting is not None else last


def _bvae_rows(model: Path, names: Sequence[str], families: Sequence[str], inputs: np.ndarray, masks: np.ndarray,
               references: Sequence[Any], budgets: Sequence[int], effort: int,
               error: Callable[[Any, np.ndarray], tuple[float, float]], latent: str = "auto",
               header_in_budget: bool = True, coded_mu_step: int | tuple[int, ...] | None = None,
               short_references: bool = True, allocate: str = "record") -> dict[str, list[dict[str, Any]]]:
    """brdfcodec's rows per family: every held-out material in one library at each budget, each family's bytes
    its records' (descriptor and payload, names aside) plus its materials' equal share of the header."""
    if allocate == "library" and not header_in_budget:
        raise ValueError("library allocation keeps the file's header within the budget: header_in_budget is true")
    import brdfcodec as bc

    decoder = bc.BrdfDecoder(model)
    name_bytes = sum(len(n.encode("utf-8")) for n in names)
    rows: dict[str, list[dict[str, Any]]] = {family: [] for family in families}
    items = [bc.MaterialInput(n, x, r, m) for n, x, r, m in zip(names, inputs, references, masks, strict=True)]
    for budget in budgets:
        # The file's fixed header is shared by the materials: --bytes starts below N by an estimate of its
        # share (library allocation's, which grows with the forms), then moves to the largest value for which
        # the file's bytes less the names, and each family's, stay within N per material.
        header = header_estimate(len(names), short_references)
        flag = budget - math.ceil(header / len(names)) if header_in_budget else budget
        if flag < _SMALLEST_RECORD:  # too few materials to share the header within this budget: no point
            continue
        def encoded(value: int) -> tuple[tuple[bytes, Any], dict[str, int], float]:
            data = bc.encode(items, model=model, latent_dtype="float16", measure_error=False, effort=effort,
                             bytes=max(value, 1), latent=latent,  # type: ignore[arg-type]
                             coded_mu_step=coded_mu_step, short_references=short_references)
            library = bc.decode(data, decoder=decoder)
            return (data, library), *_record_bytes(library, data, names, name_bytes)

        try:
            if allocate == "library":  # one encode: the library's records and header within N per material
                data = bc.encode(items, model=model, latent_dtype="float16", measure_error=False, effort=effort,
                                 bytes=budget, latent=latent,  # type: ignore[arg-type]
                                 coded_mu_step=coded_mu_step, short_references=short_references,
                                 allocate="library", groups=list(families))
                library = bc.decode(data, decoder=decoder)
                flag = budget
                record_bytes, header_share = _record_bytes(library, data, names, name_bytes)
            else:
                flag, (data, library), record_bytes, header_share = search_bytes_flag(
                    encoded, flag, budget, families, tries=8 if header_in_budget else 1)
        except RateTargetError:  # the header's share leaves less than the smallest record: no point
            continue
        library[names[0]].table(masked="unmeasured")  # warm-up (lazy imports, thread pools), not timed
        library.forget()
        for family in rows:
            chosen = [i for i, f in enumerate(families) if f == family]
            errors, seconds = [], []
            for i in chosen:  # the full decode of a record to its table, timed per material (CPU)
                start = time.perf_counter()
                table = library[names[i]].table(masked="unmeasured")
                seconds.append(time.perf_counter() - start)
                errors.append(error(references[i], table))
            without = sum(not getattr(library.record(names[i]), "has_latent", True) for i in chosen)
            rows[family].append({
                "point": "bvae", "budget_bytes": budget, "bytes_flag": max(flag, 1), "file_bytes": len(data),
                "library_materials": len(names), "header_share_bytes": header_share,
                "bytes_per_material": sum(record_bytes[names[i]] for i in chosen) / len(chosen) + header_share,
                "latent": latent, "records_without_latent": without, "short_references": short_references,
                **({} if allocate == "record" else {"allocate": allocate}),
                **({} if coded_mu_step is None else {"coded_mu_step": coded_mu_step if isinstance(
                    coded_mu_step, int) else list(coded_mu_step)}), **_error_summary(errors),
                **_decode_time(seconds)})
    return rows


def run_experiment(config: RdConfig, experiment: Experiment,
                   progress: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """Rows of one experiment: for each family of its held-out materials, brdfcodec and the PCA baselines
    at every budget (see the module docstring).

    Raises
    ------
    ValueError
        The model lists no training materials, or none of its held-out materials is in the dataset.
    """
    from brdfcodec.datasets.hdf5 import BrdfDataset
    from brdfcodec.models.pca import fit_pca, fit_pca_colour_orders
    from brdfcodec.models.store import load_manifest
    from brdfcodec.report.pca_coding import coded_pca_rows
    from brdfcodec.representation.metrics import relae_linear, relae_mapped

    manifest = load_manifest(experiment.model)
    trained = set(manifest.info.get("data", {}).get("train", []))
    if not trained:
        raise ValueError(f"{experiment.model}: model.json lists no training materials")

    def error(reference: Any, table: np.ndarray) -> tuple[float, float]:
        values = np.asarray(table, dtype=np.float64)
        return (relae_mapped(reference.values, values, reference.mask).overall,
                relae_linear(reference.values, values, reference.mask).overall)

    rows: list[dict[str, Any]] = []
    with BrdfDataset(config.dataset) as dataset:
        train_rows = [i for i, n in enumerate(dataset.names) if n in trained]
        wanted = set(experiment.held_out) if experiment.held_out is not None else None
        held = [i for i, n in enumerate(dataset.names)
                if n not in trained and (wanted is None or n in wanted)]
        if not held:
            raise ValueError(f"{experiment.label}: no held-out material of the model is in {config.dataset}")
        train_inputs = dataset.inputs(train_rows)
        # Every component the training materials support (their rank): the coded points spend bits on as many
        # as water-filling asks for; the int8/float16 points take the first k that fill the budget.
        bases = {"pca": fit_pca(train_inputs, max(1, len(train_rows) - 1)),
                 "pca-perm": fit_pca_colour_orders(train_inputs, 5 * len(train_rows) - 1)}
        if config.pca_edge_slots:
            train_inputs = _with_edge_slots((dataset.table(i) for i in train_rows), train_inputs)
            bases.update({"pca-edge": fit_pca(train_inputs, max(1, len(train_rows) - 1)),
                          "pca-perm-edge": fit_pca_colour_orders(train_inputs, 5 * len(train_rows) - 1)})
        del train_inputs
        common = {"experiment": experiment.label, "group": experiment.group or experiment.label,
                  "decode_machine": decode_machine(),
                  "model": manifest.name, "decoder_sha256": manifest.decoder_sha256,
                  "basis_sha256": manifest.basis_sha256,  # the shared basis the records were fitted on
                  "trained_materials": len(train_rows), "dataset_description": dataset.description}
        families = sorted({dataset.families[i] for i in held})
        measured = [i for family in families
                    for i in [j for j in held if dataset.families[j] == family][: config.limit]]
        if progress is not None:
            counts = ", ".join(f"{sum(dataset.families[i] == f for i in measured)} {f}" for f in families)
            progress(f"{experiment.label}: held-out materials in one library: {counts}")
        names = [dataset.names[i] for i in measured]
        inputs, masks = dataset.inputs(measured), dataset.input_masks(measured)
        references = [dataset.table(i) for i in measured]
        ours = _bvae_rows(experiment.model, names, [dataset.families[i] for i in measured], inputs, masks,
                          references, config.budgets, config.effort, error, experiment.latent,
                          config.header_in_budget, experiment.coded_mu_step, experiment.short_references,
                          experiment.allocate)
        filled = _with_edge_slots(references, inputs) if config.pca_edge_slots else inputs
        for family in families:
            chosen = [k for k, i in enumerate(measured) if dataset.families[i] == family]
            family_rows = list(ours[family])
            for label, basis in bases.items():
                coded = filled if label.endswith("-edge") else inputs
                family_rows += _pca_rows(label, basis, coded[chosen], [references[k] for k in chosen],
                                         config.budgets, error)
                family_rows += coded_pca_rows(label, basis, coded[chosen], [references[k] for k in chosen],
                                              config.budgets, error)
            rows += [{**common, "family": family, "materials": [names[k] for k in chosen], **row}
                     for row in family_rows]
    return rows


def _with_edge_slots(tables: Iterable[Any], inputs: np.ndarray) -> np.ndarray:
    """``inputs`` (the network inputs of the materials whose full tables ``tables`` are, in order) with each
    material's edge slots set to their fitted values
    (:func:`~brdfcodec.representation.edge_slots.edge_slot_targets`)."""
    from brdfcodec.representation.edge_slots import edge_slot_targets

    filled = np.array(inputs, dtype=np.float32, copy=True)
    for n, table in enumerate(tables):
        targets, weights = edge_slot_targets(table.values, table.mask)
        filled[n] = np.where(weights > 0, targets, filled[n])
    return filled


def run_config(config: RdConfig, progress: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """Rows of every experiment of a configuration, in order."""
    rows = []
    for experiment in config.experiments:
        rows += run_experiment(config, experiment, progress)
    return rows
