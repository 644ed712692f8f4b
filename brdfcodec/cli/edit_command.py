"""``bvae edit traverse | interp | graft``: new materials from latent edits, written as ``.bvae`` records."""

from __future__ import annotations

import argparse
import math
import warnings
from pathlib import Path

from brdfcodec.cli.outputs import require_output_type
from brdfcodec.cli.usage import UsageError
from brdfcodec.errors import NoLatentError
from brdfcodec.format.bvae import LatentRecord, ParsedBvae, Record, read_bvae, write_bvae

__all__ = ["parse_floats", "register"]


def parse_floats(text: str) -> list[float]:
    """``"-3,-1.5,0,1.5,3"`` to floats; NaN and infinities are refused (argparse names the option)."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected finite numbers, got {text!r}")
    return values


def _dims(text: str) -> list[int]:
    try:
        dims = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated parameter numbers, got {text!r}") from None
    if not dims or min(dims) < 1:
        raise argparse.ArgumentTypeError(f"parameter numbers start at 1 (as in the model card), got {text!r}")
    return [d - 1 for d in dims]


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``edit`` sub-command and its three operations."""
    parser = subparsers.add_parser(
        "edit",
        help="latent edits: traverse a parameter, interpolate materials, graft a green channel",
        description="Make new materials by editing latent codes; the result is a .bvae file of new records "
        "(decode or render it like any other). Parameters are numbered from 1, as in the model card.",
    )
    ops = parser.add_subparsers(dest="operation", metavar="OPERATION")
    ops.required = True

    traverse = ops.add_parser("traverse", help="vary one parameter, the others fixed")
    traverse.add_argument("input", type=Path, metavar="IN.bvae")
    traverse.add_argument("--material", help="material to start from (default: the only one)")
    traverse.add_argument("--dim", type=int, required=True, help="parameter number, from 1")
    traverse.add_argument("--values", type=parse_floats, default=[-3.0, -1.5, 0.0, 1.5, 3.0],
                          help="offsets in prior σ (default -3,-1.5,0,1.5,3; write --values=-2,0,2 when the "
                          "first is negative), or values with --absolute")
    traverse.add_argument("--absolute", action="store_true", help="--values are the parameter's new values")

    interp = ops.add_parser("interp", help="interpolate two materials, linearly or per factor")
    interp.add_argument("input", type=Path, metavar="IN.bvae")
    interp.add_argument("a", metavar="A", help="first material (NAME, or OTHER.bvae:NAME)")
    interp.add_argument("b", metavar="B", help="second material (NAME, or OTHER.bvae:NAME)")
    interp.add_argument("--t", type=parse_floats, default=[0.5], help="interpolation weights of B (default 0.5)")
    interp.add_argument("--factors-from-a", type=_dims, metavar="DIMS",
                        help="per-factor: take these parameters (e.g. 4,5) from A and the rest from B")

    graft = ops.add_parser("graft", help="green-channel grafting: two extra colour parameters (paper §5)")
    graft.add_argument("input", type=Path, metavar="IN.bvae")
    graft.add_argument("--material", help="material to graft (default: the only one)")
    source = graft.add_mutually_exclusive_group(required=True)
    source.add_argument("--values", type=parse_floats, help="the grafted values (one per colour dimension)")
    source.add_argument("--fit", type=Path, metavar="SOURCE.binary",
                        help="fit all parameters of the graft to this MERL file")

    for op in (traverse, interp, graft):
        op.add_argument("-o", "--output", type=Path, required=True, help="output .bvae file")
        op.add_argument("--force", action="store_true", help="replace an existing output file")
        op.set_defaults(handler=run)


def _editable(record: Record, path: str | Path) -> Record:
    """The record, unless it has no latent code to edit (a basis-only record, format 2.1): then
    :class:`NoLatentError` naming the file and the record, before anything is written."""
    if not getattr(record, "has_latent", True):
        raise NoLatentError(record.name, path)
    return record


def _pick(library: ParsedBvae, path: Path, name: str | None) -> Record:
    if name is None:
        if len(library.records) != 1:
            raise UsageError(f"{path}: holds {len(library.records)} materials; name one with --material")
        return _editable(library.records[0], path)
    return _editable(library.record(name), path)


def _operand(library: ParsedBvae, path: Path, spec: str) -> tuple[Record, ParsedBvae]:
    if ":" in spec and spec.split(":", 1)[0].endswith(".bvae"):
        other_path, name = spec.split(":", 1)
        other = read_bvae(other_path)
        ours, theirs = sorted((library.header.decoder.sha256, other.header.decoder.sha256), key=len)
        if not theirs.startswith(ours):  # a short reference (format 2.6) names a decoder by its hash's first bytes
            raise ValueError(f"{other_path}: made for another decoder than {path}; both must use the same model")
        return _editable(other.record(name), other_path), other
    return _editable(library.record(spec), path), library


def _parameter_count(record: Record) -> int:
    from brdfcodec.edit.latent_edits import parameter_vector

    return int(parameter_vector(record).size)


def _check_parameters(numbers_from_zero: list[int], record: Record, option: str) -> None:
    """Parameter numbers as typed (from 1) must exist in the record: a usage error otherwise."""
    count = _parameter_count(record)
    wrong = [d + 1 for d in numbers_from_zero if not 0 <= d < count]
    if wrong:
        raise UsageError(f"{option}: parameter {wrong[0]} does not exist; {record.name} has parameters 1 to {count}")


def run(args: argparse.Namespace) -> int:
    """Apply the edit and write the new records."""
    from brdfcodec.edit import latent_edits as edit
    require_output_type(args.output, f"edit {args.operation}", "edited materials", (".bvae",))
    library = read_bvae(args.input)
    records: list[Record]
    if args.operation == "traverse":
        record = _pick(library, args.input, args.material)
        _check_parameters([args.dim - 1], record, "--dim")
        records = edit.traverse(record, args.dim - 1, args.values, unit="absolute" if args.absolute else "sigma")
    elif args.operation == "interp":
        a, _ = _operand(library, args.input, args.a)
        b, _ = _operand(library, args.input, args.b)
        if args.factors_from_a is not None:
            _check_parameters(args.factors_from_a, a, "--factors-from-a")
            records = [edit.mix_factors(a, b, args.factors_from_a)]
        else:
            records = [edit.interpolate(a, b, t) for t in args.t]
    else:
        record = _pick(library, args.input, args.material)
        if not isinstance(record, LatentRecord):
            raise ValueError(f"{record.name} is already a graft")
        from brdfcodec.codec import BrdfDecoder

        decoder = BrdfDecoder.for_header(library.header)
        if getattr(record, "basis", None) is not None or getattr(record, "detail", None) is not None:
            print(f"{record.name}: a graft record has no layers (spec §4.4, \"Edits\"): the graft is made of its "
                  "base code and leaves its enhancement layers out")
        if args.values is not None:
            if len(args.values) != len(decoder.colour_dims):
                raise UsageError(f"the model has {len(decoder.colour_dims)} colour dimensions "
                                 f"({', '.join(str(d + 1) for d in decoder.colour_dims)}); give one value each")
            records = [edit.graft(record, args.values, decoder.colour_dims)]
        else:
            from brdfcodec.codec import measure, prepare_source
            from brdfcodec.datasets.hdf5 import material_arrays
            from brdfcodec.io.inputs import read_measured

            source = prepare_source(read_measured(args.fit))  # MERL or RGL; clamped as for compress
            inputs, mask = material_arrays(source)
            base = record.base() if hasattr(record, "base") else record  # a layered record: its base code
            alone = measure(base, decoder, source)
            before = alone.meta.get("relae", {}).get("mapped", float("nan"))
            fitted = measure(edit.fit_graft(decoder, base, inputs, mask), decoder, source)
            if "relae" not in fitted.meta:
                raise ValueError(f"{args.fit}: the material reflects nothing (black): there is no colour to fit")
            after = fitted.meta["relae"]["mapped"]
            print(f"{record.name}: RelAE (mapped) {before:.4f} from the code alone, "
                  f"{after:.4f} with the fitted graft")
            if after < before:
                records = [fitted]
            else:  # the fit (on the kept slices) lost on the full table: keep the better record, and say so
                warnings.warn(f"{record.name}: the fitted graft ({after:.4f}) is no better than the code alone "
                              f"({before:.4f}); writing the code alone, as {record.name}", stacklevel=1)
                records = [alone]
    size = write_bvae(args.output, records, library.header.decoder, latent_dtype=library.header.latent_dtype,
                      overwrite=args.force)
    print(f"wrote {args.output}: {len(records)} material{'s' if len(records) != 1 else ''} "
          f"({', '.join(r.name for r in records)}), {size:,} bytes")
    return 0
