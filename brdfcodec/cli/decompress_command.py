"""``bvae decompress IN.bvae -o OUT``: decode materials to MERL ``.binary``, ``.npy``, EXR slices or RGL ``.bsdf``."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from tqdm import tqdm

from brdfcodec.cli.legend import RELAE_LEGEND
from brdfcodec.cli.outputs import is_folder_request, require_output_type
from brdfcodec.cli.usage import UsageError
from brdfcodec.conventions import N_PHI_D
from brdfcodec.format.material_names import material_file_path, shown_name
from brdfcodec.io.atomic import check_output_path
from brdfcodec.io.table_output import TABLE_FORMATS, table_format_of, write_table

if TYPE_CHECKING:
    from brdfcodec.codec import DecodedMaterial
    from brdfcodec.io.merl import MerlBRDF
    from brdfcodec.io.rgl_writer import RglResolution

__all__ = ["parse_bins", "register"]


def parse_bins(text: str) -> list[int]:
    """``"0,90,170-179"`` to a sorted list of φd bins, each in [0, 180)."""
    bins: set[int] = set()
    try:
        for part in text.split(","):
            low, _, high = part.strip().partition("-")
            bins.update(range(int(low), int(high or low) + 1))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected bins like 0,90,170-179, got {text!r}") from None
    if not bins or min(bins) < 0 or max(bins) >= N_PHI_D:
        raise argparse.ArgumentTypeError(f"φd bins must lie in [0, {N_PHI_D - 1}], got {text!r}")
    return sorted(bins)


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``decompress`` sub-command."""
    parser = subparsers.add_parser(
        "decompress",
        help="decode a .bvae file to MERL .binary, .npy, EXR slices or RGL .bsdf",
        description="Decode materials of a .bvae file with the decoder it names (found by SHA-256). The output "
        "type follows the suffix, and so does the unit: .binary (MERL) and .npy (float32 table) hold MERL's "
        "stored units, -1 below the horizon; .exr (one 90x90 RGB part per phi_d bin, for viewers) holds "
        "reflectance in 1/sr, 0 below the horizon, and says so in each part's header; .bsdf (RGL tensor file "
        "for Mitsuba's built-in measured BSDF). "
        "OUT is one file, for one material, unless a folder is asked for: --output-dir DIR, or -o ending in a "
        "slash (out/), naming an existing folder, or without an extension (out); the folder receives NAME.binary "
        "for each material (or the type of --format). Several materials and a file name (-o x.binary) are "
        "refused: choose one with --material, or give a folder.",
    )
    parser.add_argument("input", type=Path, metavar="IN.bvae")
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("-o", "--output", metavar="OUT",
                       help="output file (.binary, .npy, .exr or .bsdf) for one material, or folder (out/) for any "
                       "number")
    where.add_argument("--output-dir", type=Path, metavar="DIR",
                       help="output folder, created if needed: NAME.binary (or --format's type) for each material")
    parser.add_argument("--material", action="append", help="material to decode (repeatable; default: all)")
    parser.add_argument("--format", choices=[s.lstrip(".") for s in TABLE_FORMATS], default=None,
                        help="file type written into an output folder (default binary)")
    parser.add_argument("--phi-d", type=parse_bins, metavar="BINS",
                        help="only these phi_d bins, e.g. 0,90,170-179 (.npy and .exr only)")
    parser.add_argument("--masked", choices=("unmeasured", "zero"), default=None,
                        help="below-horizon entries of .binary and .npy outputs: -1 as MERL's unmeasured marker "
                        "(default), or 0 (.exr always holds 0 there)")
    parser.add_argument("--reference", type=Path, metavar="SOURCE",
                        help="the original material: a MERL .binary or RGL .bsdf file, or an NBRDF fit (NAME.h5, or "
                        "the zip or folder holding the material of that name); print the RelAE of the decoded table "
                        "against it")
    parser.add_argument("--force", action="store_true", help="replace existing output files")
    parser.add_argument("--bsdf-theta-i", type=int, default=32, metavar="N",
                        help=".bsdf: incident elevations, uniform over [0, 90] degrees (default 32)")
    parser.add_argument("--bsdf-grid", type=int, default=32, metavar="N",
                        help=".bsdf: RGB and luminance samples per axis (default 32, as the RGL database)")
    parser.add_argument("--bsdf-vndf", type=int, default=128, metavar="N",
                        help=".bsdf: NDF and VNDF samples per axis (default 128, as the RGL database)")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Decode and write; every output is written atomically."""
    from brdfcodec.codec import MaterialLibrary

    with MaterialLibrary(args.input) as library:
        names = args.material or library.names
        for name in names:
            library.record(name)  # unknown names and corrupt records fail before anything is written
        folder = _output_folder(args, len(names))
        single = len(names) == 1
        if folder is None:
            targets = {names[0]: check_output_path(args.output, overwrite=args.force)}
        else:
            if folder.exists() and not folder.is_dir():
                raise UsageError(f"{folder}: is a file; the output folder must be a folder")
            file_format = args.format or "binary"
            # A material name never chooses a folder: material_file_path keeps every file inside the folder
            # (and refuses bad names before anything is created).
            targets = {n: material_file_path(folder, n, file_format) for n in names}
            if folder.is_dir():  # a new folder holds no file to replace
                for target in targets.values():
                    check_output_path(target, overwrite=args.force)
        kinds = {table_format_of(target) for target in targets.values()}
        rgl_resolution = _rgl_resolution(args) if "bsdf" in kinds else None
        if "bsdf" in kinds and args.phi_d is not None:
            raise UsageError("--phi-d: an RGL .bsdf file needs all 180 phi_d bins (use .npy or .exr for a subset)")
        if "binary" in kinds and args.phi_d is not None:
            raise UsageError("--phi-d: a MERL .binary file needs all 180 phi_d bins (use .npy or .exr for a subset)")
        _check_masked(args.masked, kinds)
        if args.reference is not None and not single:
            raise UsageError("--reference needs a single material (use --material)")
        # Measured before writing: a bad reference must not fail the command after its output exists.
        reference_line = None if args.reference is None else _reference_error(args.reference, library[names[0]])
        if folder is not None:  # created once every check has passed
            folder.mkdir(parents=True, exist_ok=True)
        legend = False
        for name, target in tqdm(targets.items(), desc="decompress", unit="material", disable=len(targets) < 2 or None):
            material = library[name]
            table = material.table(phi_d_bins=args.phi_d, masked=args.masked or "unmeasured")
            note = _stored_error_note(material.record.meta)  # before writing: nothing may fail after a write
            kind = write_table(target, table, phi_d_bins=args.phi_d, overwrite=args.force,
                               rgl_resolution=rgl_resolution, name=name)
            print(f"wrote {target} ({shown_name(name)}, {kind}){note}")  # format characters escaped (§4.3)
            legend = legend or bool(note)
        if reference_line is not None:
            print(reference_line)
        if legend or reference_line is not None:
            print(RELAE_LEGEND)
    return 0


def _output_folder(args: argparse.Namespace, count: int) -> Path | None:
    """The output folder, or None for one output file; usage errors for a file name that cannot be.

    A folder only when asked (:func:`~brdfcodec.cli.outputs.is_folder_request`): ``--output-dir``, or ``-o``
    ending in a slash, naming an existing folder, or without an extension. Otherwise ``-o`` names one file of a
    type :func:`write_table` writes, for one material.
    """
    if args.output_dir is not None:
        return Path(args.output_dir)
    if is_folder_request(args.output):
        return Path(args.output)
    suffix = require_output_type(args.output, "decompress", "decoded tables", tuple(TABLE_FORMATS))
    if count > 1:
        stem = Path(args.output).with_suffix("")
        raise UsageError(f"{args.output}: {count} materials to decode, and a {suffix} file holds one: choose one "
                         f"with --material NAME, or write them all into a folder (-o {stem}/ or --output-dir "
                         f"{stem})")
    if args.format is not None and f".{args.format}" != suffix:
        raise UsageError(f"--format {args.format} names the type of files in an output folder, and {args.output} "
                         f"is a {suffix} file: leave --format out, or give a folder")
    return None


def _check_masked(masked: str | None, kinds: set[str]) -> None:
    """Refuse a ``--masked`` choice the output type cannot hold (a UsageError naming the flag)."""
    if masked == "unmeasured" and "exr" in kinds:
        raise UsageError("--masked unmeasured: an .exr file holds reflectance in 1/sr with 0 below the horizon; "
                         "use .binary or .npy to keep MERL's -1 marker")
    if masked is not None and "bsdf" in kinds:
        raise UsageError("--masked: an RGL .bsdf file holds no below-horizon entries; leave --masked out")


def _rgl_resolution(args: argparse.Namespace) -> RglResolution:
    """The ``--bsdf-*`` sizes as an RglResolution (a UsageError naming the flag when out of range)."""
    from brdfcodec.io.rgl_writer import RglResolution

    for flag, value, upper in (("--bsdf-theta-i", args.bsdf_theta_i, 512), ("--bsdf-grid", args.bsdf_grid, 512),
                               ("--bsdf-vndf", args.bsdf_vndf, 2048)):
        if not 2 <= value <= upper:
            raise UsageError(f"{flag} must lie in [2, {upper}], got {value}")
    try:  # each size in range, but together more than the writer's largest file (issue 49, R3-09)
        return RglResolution(theta_i=args.bsdf_theta_i, ndf=args.bsdf_vndf, vndf=args.bsdf_vndf,
                             luminance=args.bsdf_grid)
    except ValueError as error:
        raise UsageError(f"--bsdf-theta-i, --bsdf-vndf, --bsdf-grid: {error}") from None


def _stored_error_note(meta: dict) -> str:
    """`` (RelAE at encode time: mapped 0.0123)`` when the record carries a measurement, else ``""``."""
    stored = meta.get("relae")
    if isinstance(stored, dict) and isinstance(stored.get("mapped"), int | float):
        return f" (RelAE at encode time: mapped {float(stored['mapped']):.4f})"
    return ""


def _reference_source(path: Path, name: str) -> MerlBRDF:
    """The ``--reference`` table: a MERL or RGL file or an NBRDF fit, or the material ``name`` of an NBRDF
    archive or folder (:func:`~brdfcodec.datasets.sources.input_sources`)."""
    from brdfcodec.datasets.sources import input_sources

    sources = input_sources(path)
    if len(sources) > 1:
        matching = [source for source in sources if source.name == name]
        if not matching:
            raise UsageError(f"--reference {path}: holds {len(sources)} materials and none named {name!r}; give the "
                             "original material's own file")
        sources = matching
    return sources[0].load().brdf


def _reference_error(path: Path, material: DecodedMaterial) -> str:
    from brdfcodec.codec import measure

    relae = measure(material.record, material.decoder, _reference_source(path, material.name)).meta.get("relae")
    if relae is None:
        raise ValueError(f"{path}: the reference reflects nothing (black): its RelAE is undefined (0/0)")
    return f"RelAE against {path}: mapped {relae['mapped']:.4f}, linear {relae['linear']:.4f}"
