"""``bvae compress IN... -o OUT.bvae``: encode MERL files, folders or a dataset into one ``.bvae`` file."""

from __future__ import annotations

import argparse
import math
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from brdfcodec.cli.legend import RELAE_LEGEND
from brdfcodec.cli.outputs import require_output_type
from brdfcodec.cli.usage import UsageError
from brdfcodec.datasets.hdf5 import HDF5_SIGNATURE
from brdfcodec.datasets.nbrdf import is_nbrdf_weight_file
from brdfcodec.datasets.sources import MaterialSource, input_sources
from brdfcodec.format.bvae import Record, without_provenance, write_bvae
from brdfcodec.io.atomic import check_output_path
from brdfcodec.representation import network_input_from_table

if TYPE_CHECKING:
    from brdfcodec.codec import BrdfEncoder, MaterialInput

__all__ = ["register"]

@dataclass(frozen=True)
class _Item:
    """One material to encode: its name, where it comes from, and how to load it."""

    name: str
    origin: str
    load: Callable[[], MaterialInput]


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``compress`` sub-command."""
    parser = subparsers.add_parser(
        "compress",
        help="encode MERL .binary or RGL .bsdf files (or a folder, or a dataset) into a .bvae file",
        description="Encode measured BRDFs into latent codes and write them, with a reference to the decoder, "
        "as one .bvae file (one material, or a library of many). Prints the RelAE of each decoded material "
        "against its source.",
    )
    parser.add_argument("inputs", nargs="+", type=Path, metavar="IN",
                        help="MERL .binary or RGL .bsdf files, folders of them, or a dataset file (.h5)")
    parser.add_argument("-o", "--output", type=Path, required=True, help="output .bvae file")
    parser.add_argument("--model", help="model folder, model name (editing: the opt-in editing model) or decoder "
                        "SHA-256 (default: the shipped model)")
    parser.add_argument("--float16", action="store_true", help="store latents as float16 (half the payload)")
    parser.add_argument("--split", choices=("train", "validation"), help="with a dataset: only this split")
    parser.add_argument("--no-measure", action="store_true", help="skip decoding to measure RelAE")
    parser.add_argument("--provenance", action="store_true",
                        help="store each material's provenance in the file: source SHA-256 and kind, measured RelAE, "
                        "encoder, effort and rate control (by default the file holds names and records only)")
    parser.add_argument("--full-references", action="store_true",
                        help="name the decoder and the shared basis by their full SHA-256 and write every record "
                        "form in full, for readers older than format 2.6 (by default the first 8 bytes of each, 48 "
                        "bytes less a file with basis layers, and forms that differ from an earlier one in a few "
                        "numbers as those numbers, format 2.7)")
    parser.add_argument("--batch-size", type=int, default=8, help="materials encoded at once (default 8)")
    parser.add_argument("--force", action="store_true", help="replace an existing output file")
    # --- issue 14: refinement and rate control (brdfcodec.layers)
    parser.add_argument("--effort", type=int, choices=(0, 1, 2, 3), default=1,
                        help="latent refinement at encode time: 0 (encoder only) to 3 (slowest); default 1")
    target = parser.add_mutually_exclusive_group()
    target.add_argument("--bytes", type=int, metavar="N",
                        help="largest quality within N bytes per material: what each adds to the file beyond its "
                        "name, its record and its index entry (adds enhancement "
                        "layers: basis coefficients, then a detail layer; from 10 B, the base alone stored "
                        "compact: μ as int8 on a fixed grid, or with a step where it does not fit and the budget "
                        "has room, from 14 B with basis coefficients (with --sigma, from 15 B); "
                        "from 6 B with --latent auto, without a latent)")
    target.add_argument("--max-relae", type=float, metavar="X",
                        help="smallest record whose measured RelAE on its material is at most X (adds enhancement "
                        "layers)")
    parser.add_argument("--metric", choices=("mapped", "linear"), default=None,
                        help="RelAE used by --max-relae (default mapped)")
    parser.add_argument("--no-basis", action="store_true",
                        help="with --bytes/--max-relae: no basis layer, only the detail layer")
    parser.add_argument("--project-base", nargs="?", const="always", choices=("auto", "always", "never"),
                        default=None, metavar="WHEN",
                        help="with --bytes/--max-relae: project the base decode on the shared basis in records with "
                        "a basis layer (format 1.6): auto (default: per material, where it lowers the error, in "
                        "records without a detail layer), always (the flag alone) or never; projecting usually lowers "
                        "the error on materials the model was not trained on, at some decode time")
    parser.add_argument("--allocate", choices=("record", "library"), default=None,
                        help="with --bytes N: record (default) makes each record the best it can be within N bytes "
                        "of its own, the file's header on top; library keeps the whole file within N bytes per "
                        "material besides the names, its header included, and gives each material the bytes where "
                        "they lower the library's error most (records from about 0.6 to 2 N; about 8 times the "
                        "encode time)")
    parser.add_argument("--latent", choices=("always", "auto"), default=None,
                        help="with --bytes/--max-relae: always (default) keeps an editable latent code in every "
                        "record; auto may write a record without a latent code where its error is lower (format "
                        "2.1: the model's mean plus basis coefficients; from 6 B), giving up the latent: such a "
                        "record decodes like any other, but cannot be edited, traversed, interpolated or grafted, "
                        "nor shown on the studio's sliders")
    parser.add_argument("--sigma", action="store_true",
                        help="also store the posterior width σ (by default a record stores μ alone, format 2.2, and "
                        "reads back with σ = 1; under --bytes σ's bytes go to the layers instead): the shipped "
                        "model's σ carries no information, see its model card")
    parser.add_argument("--basis-coding", choices=("auto", "packed", "coded", "int8"), default="auto",
                        help="with --bytes/--max-relae: how records without a detail layer store basis "
                        "coefficients: auto (default: rate control makes both packed and coded and keeps the lower "
                        "error per material), packed (format 2.3: later vectors get fewer bits at one step, "
                        "more coefficients in the same bytes), coded (format 2.4: one step, the integers "
                        "arithmetic-coded under a Laplace prior whose spread falls with the vector's rank) or int8 "
                        "(one byte each, readable by format 2.2 readers); under auto and coded, rate control also "
                        "offers records whose mu rides in the coded layer on a coarser grid (format 2.5)")
    parser.set_defaults(handler=run)


def _source_item(source: MaterialSource) -> _Item:
    """A material file, or one of an NBRDF archive or folder, tabulated on the MERL grid when loaded."""

    def load() -> MaterialInput:
        from brdfcodec.codec import MaterialInput, prepare_source

        brdf = prepare_source(source.load().brdf)  # nothing measured: an error; beyond range: clamped
        inputs, mask = network_input_from_table(brdf.values, brdf.mask)
        return MaterialInput(source.name, inputs, brdf, mask)

    return _Item(source.name, source.origin, load)


def _dataset_items(path: Path, split: str | None) -> Iterator[_Item]:
    from brdfcodec.datasets.hdf5 import BrdfDataset

    with BrdfDataset(path) as dataset:
        indices = dataset.indices(split)
        names = [dataset.names[i] for i in indices]
        has_tables = dataset.has_tables

    for index, name in zip(indices, names, strict=True):

        def load(index: int = index, name: str = name) -> MaterialInput:
            from brdfcodec.codec import MaterialInput

            with BrdfDataset(path) as dataset:
                table = dataset.table(index) if has_tables else None
                return MaterialInput(name, dataset.inputs([index])[0], table, dataset.input_masks([index])[0])

        yield _Item(name, f"{path}[{name}]", load)


def collect_items(inputs: list[Path], split: str | None) -> list[_Item]:
    """Every material named by the inputs, in order; names must be unique."""
    items: list[_Item] = []
    for path in inputs:
        if not path.is_dir():
            with open(path, "rb") as stream:  # FileNotFoundError names the file
                head = stream.read(8)
            if head == HDF5_SIGNATURE and not is_nbrdf_weight_file(path):
                items += list(_dataset_items(path, split))
                continue
        # MERL and RGL files, NBRDF fits (NAME.h5, their zip, their folder), folders of them: told by content
        items += [_source_item(source) for source in input_sources(path)]
    seen: dict[str, str] = {}
    for item in items:
        if item.name in seen:
            raise ValueError(f"two inputs give the material name {item.name!r}: {seen[item.name]} and {item.origin}")
        seen[item.name] = item.origin
    return items


#: Largest ``--bytes`` accepted: beyond every record a file can hold (a detail layer is at most 64 MiB).
MAX_BYTES_BUDGET = 1 << 30


def _check_bytes_floor(budget: int, model: str | None, latent_itemsize: int, basis: bool,
                       without_latent: bool = False, store_sigma: bool = False) -> None:
    """Refuse a ``--bytes`` below the smallest record the model can write (a usage error, exit 2); records
    without a latent (``without_latent``: ``--latent auto``) count where the model has a basis and a linear path."""
    from brdfcodec.codec.rate import smallest_bytes_budget
    from brdfcodec.models.registry import resolve_manifest

    manifest = resolve_manifest(model)  # brdfcodec.codec.resolve_model's lookup, without importing torch
    has_basis = basis and manifest.basis_sha256 is not None
    floor = smallest_bytes_budget(manifest.config.latent_dim, latent_itemsize, has_basis,
                                  without_latent=has_basis and without_latent and bool(manifest.config.linear_basis),
                                  store_sigma=store_sigma)
    if budget < floor:
        raise UsageError(f"--bytes {budget} is below the smallest record model {manifest.name} can write "
                         f"({floor} bytes per material)")


def _absolute_error(record: Record, items: list[_Item], encoder: BrdfEncoder) -> float:
    """Mean absolute reflectance error (1/sr) of a near-black material's decode against its source (reloaded)."""
    from brdfcodec.representation.metrics import mean_absolute_error

    item = next(item for item in items if item.name == record.name)
    source = item.load().source
    if source is None:  # measured against a source, so it has one
        return float("nan")
    decoded = encoder.decoder.decode(record, masked="keep").astype(np.float64)
    return mean_absolute_error(source.values, decoded, source.mask).overall


def _latent_summary(records: list[Record], dtype: str) -> str:
    """What the records store of a latent code: ``latents float32``, ``latents float16 in 3 of 5 records``, or
    ``no latent (basis-only records, not editable)`` when none has one (format 2.1)."""
    with_latent = sum(1 for record in records if getattr(record, "has_latent", True))
    if with_latent == len(records):
        return f"latents {dtype}"
    if with_latent == 0:
        return "no latent (basis-only records, not editable)"
    return f"latents {dtype} in {with_latent} of {len(records)} records"


def run(args: argparse.Namespace) -> int:
    """Encode every input (:func:`brdfcodec.codec.encode_records`), write the file, print RelAE and sizes."""
    from brdfcodec.codec import BrdfEncoder, encode_records
    from brdfcodec.codec.library_budget import allocate_library

    require_output_type(args.output, "compress", "compressed materials", (".bvae",))
    if args.batch_size < 1:
        raise UsageError("--batch-size must be at least 1")
    if args.bytes is not None and not 1 <= args.bytes <= MAX_BYTES_BUDGET:
        raise UsageError(f"--bytes must be a number of bytes from 1 to {MAX_BYTES_BUDGET:,} (a record holds at most "
                         f"a 64 MiB detail layer), got {args.bytes}")
    if args.max_relae is not None and not (math.isfinite(args.max_relae) and args.max_relae > 0):
        raise UsageError(f"--max-relae must be a positive number, got {args.max_relae}")
    if args.metric is not None and args.max_relae is None:
        raise UsageError("--metric chooses the RelAE of --max-relae; give --max-relae too")
    if args.project_base is not None and (args.no_basis or (args.bytes is None and args.max_relae is None)):
        raise UsageError("--project-base applies to records with a basis layer: give --bytes or --max-relae, "
                         "without --no-basis")
    if args.allocate is not None and args.bytes is None:
        raise UsageError("--allocate spreads a size budget: give --bytes")
    if args.latent is not None and args.bytes is None and args.max_relae is None:
        raise UsageError("--latent chooses between the records of rate control: give --bytes or --max-relae")
    latent = args.latent or "always"
    dtype = "float16" if args.float16 else "float32"
    if args.bytes is not None:  # the floor, from the model's manifest: before loading the model or any input
        _check_bytes_floor(args.bytes, args.model, 2 if args.float16 else 4, not args.no_basis, latent == "auto",
                           args.sigma)
    check_output_path(args.output, overwrite=args.force)
    items = collect_items(args.inputs, args.split)
    encoder = BrdfEncoder(
        args.model, effort=args.effort, bytes=args.bytes, max_relae=args.max_relae, metric=args.metric or "mapped",
        basis=not args.no_basis, project_base=args.project_base or "auto",
        latent_dtype=dtype, latent=latent, store_sigma=args.sigma, basis_coding=args.basis_coding,
    )
    with tqdm(total=len(items), desc="compress", unit="material", disable=len(items) < 2 or None) as bar:
        if args.allocate == "library":
            records: list[Record] = allocate_library(
                (item.load() for item in items), encoder, count=len(items), latent_dtype=dtype,
                short_references=not args.full_references, provenance=args.provenance, batch_size=args.batch_size,
                decoder=None if args.no_measure else encoder.decoder, on_batch=bar.update,
            )
        else:
            records = encode_records(
                (item.load() for item in items),
                encoder=encoder,
                measure_error=not args.no_measure,
                batch_size=args.batch_size,
                on_batch=lambda batch: bar.update(len(batch)),
            )
    lines = []
    for record in records:
        # a record without a latent (format 2.1) decodes like any other, but edits refuse it: say so
        tag = "" if getattr(record, "has_latent", True) else "  (no latent: basis only, not editable)"
        if "relae" in record.meta:
            relae = record.meta["relae"]
            lines.append(f"  {record.name:<32} RelAE mapped {relae['mapped']:.4f}  linear {relae['linear']:.4f}{tag}")
        elif args.no_measure or "source_sha256" not in record.meta:
            why = "--no-measure" if args.no_measure else "no source table"
            lines.append(f"  {record.name:<32} (RelAE not measured: {why}){tag}")
        else:  # near black: a ratio to nothing means nothing; the absolute error does (issue 49)
            error = _absolute_error(record, items, encoder)
            lines.append(f"  {record.name:<32} near black (RelAE undefined): mean absolute error {error:.3g} /sr"
                         f"{tag}")
    if encoder.reference is None:  # loaded from a model folder, so it has one
        raise RuntimeError("the encoder has no decoder reference")
    stored = records if args.provenance else without_provenance(records)
    size = write_bvae(args.output, stored, encoder.reference, latent_dtype=dtype, overwrite=args.force,
                      short_references=not args.full_references)
    print("\n".join(lines))
    measured = [r.meta["relae"]["mapped"] for r in records if "relae" in r.meta]
    if measured:
        print(f"  mean RelAE (mapped) over {len(measured)} materials: {np.mean(measured):.4f}")
        print(f"  {RELAE_LEGEND}")
    if encoder.manifest is not None:
        from brdfcodec.models.card_range import card_range_warning

        for record in records:
            warning = card_range_warning(record.name, record.meta, encoder.manifest.info, encoder.manifest.name)
            if warning is not None:
                warnings.warn(warning, stacklevel=1)
    model_name = encoder.manifest.name if encoder.manifest is not None else "?"
    print(
        f"wrote {args.output}: {len(records)} material{'s' if len(records) != 1 else ''}, {size:,} bytes "
        f"({size / len(records):.1f} bytes per material; {_latent_summary(records, dtype)}; decoder {model_name} "
        f"{encoder.reference.sha256[:12]}…)"
    )
    return 0
