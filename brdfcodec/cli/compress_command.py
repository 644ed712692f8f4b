"""``bvae compress IN... -o OUT.bvae``: encode MERL files, folders or a dataset into one ``.bvae`` file."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from brdfcodec.atomic import check_output_path
from brdfcodec.bvae_format import Record, write_bvae
from brdfcodec.cli.info_command import HDF5_SIGNATURE
from brdfcodec.dataset import material_arrays
from brdfcodec.merl import MerlBRDF, read_merl

__all__ = ["register"]

@dataclass(frozen=True)
class _Item:
    """One material to encode: its name and how to load it (table if known, network input)."""

    name: str
    origin: str
    load: Callable[[], tuple[MerlBRDF | None, np.ndarray]]


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``compress`` sub-command."""
    parser = subparsers.add_parser(
        "compress",
        help="encode MERL .binary files (or a folder, or a dataset) into a .bvae file",
        description="Encode measured BRDFs into latent codes and write them, with a reference to the decoder, "
        "as one .bvae file (one material, or a library of many). Prints the RelAE of each decoded material "
        "against its source.",
    )
    parser.add_argument("inputs", nargs="+", type=Path, metavar="IN",
                        help="MERL .binary files, folders of them, or a dataset file (.h5)")
    parser.add_argument("-o", "--output", type=Path, required=True, help="output .bvae file")
    parser.add_argument("--model", help="model folder or decoder SHA-256 (default: the shipped model)")
    parser.add_argument("--float16", action="store_true", help="store latents as float16 (half the payload)")
    parser.add_argument("--split", choices=("train", "validation"), help="with a dataset: only this split")
    parser.add_argument("--no-measure", action="store_true", help="skip decoding to measure RelAE")
    parser.add_argument("--batch-size", type=int, default=8, help="materials encoded at once (default 8)")
    parser.add_argument("--force", action="store_true", help="replace an existing output file")
    parser.set_defaults(handler=run)


def _merl_item(path: Path) -> _Item:
    def load() -> tuple[MerlBRDF | None, np.ndarray]:
        from brdfcodec.codec import prepare_source

        brdf = prepare_source(read_merl(path))  # nothing measured: an error; beyond range: clamped, with a warning
        return brdf, material_arrays(brdf)[0]

    return _Item(path.stem, str(path), load)


def _dataset_items(path: Path, split: str | None) -> Iterator[_Item]:
    from brdfcodec.dataset import BrdfDataset

    with BrdfDataset(path) as dataset:
        indices = dataset.indices(split)
        names = [dataset.names[i] for i in indices]
        has_tables = dataset.has_tables

    for index, name in zip(indices, names, strict=True):

        def load(index: int = index) -> tuple[MerlBRDF | None, np.ndarray]:
            with BrdfDataset(path) as dataset:
                table = dataset.table(index) if has_tables else None
                return table, dataset.inputs([index])[0]

        yield _Item(name, f"{path}[{name}]", load)


def collect_items(inputs: list[Path], split: str | None) -> list[_Item]:
    """Every material named by the inputs, in order; names must be unique."""
    items: list[_Item] = []
    for path in inputs:
        if path.is_dir():
            files = sorted(p for p in path.iterdir() if p.suffix == ".binary" and p.is_file())
            if not files:
                raise FileNotFoundError(f"{path}: folder holds no .binary file")
            items += [_merl_item(p) for p in files]
            continue
        with open(path, "rb") as stream:  # FileNotFoundError names the file
            head = stream.read(8)
        if head == HDF5_SIGNATURE:
            items += list(_dataset_items(path, split))
        else:
            items.append(_merl_item(path))
    seen: dict[str, str] = {}
    for item in items:
        if item.name in seen:
            raise ValueError(f"two inputs give the material name {item.name!r}: {seen[item.name]} and {item.origin}")
        seen[item.name] = item.origin
    return items


def run(args: argparse.Namespace) -> int:
    """Encode every input, write the file, print per-material RelAE and sizes."""
    from brdfcodec.codec import BrdfDecoder, BrdfEncoder, measure

    if args.batch_size < 1:
        raise ValueError("--batch-size must be at least 1")
    check_output_path(args.output, overwrite=args.force)
    if args.output.suffix != ".bvae":
        raise ValueError(f"{args.output}: the output must end in .bvae")
    items = collect_items(args.inputs, args.split)
    encoder = BrdfEncoder(args.model)
    decoder = None if args.no_measure else BrdfDecoder(encoder.manifest)
    records: list[Record] = []
    lines: list[str] = []
    with tqdm(total=len(items), desc="compress", unit="material", disable=len(items) < 2 or None) as bar:
        for start in range(0, len(items), args.batch_size):
            chunk = items[start : start + args.batch_size]
            loaded = [item.load() for item in chunk]
            mu, sigma = encoder.posterior_from_inputs(np.stack([inputs for _, inputs in loaded]))
            sources = [brdf for brdf, _ in loaded]
            for item, brdf, record in zip(
                chunk, sources, encoder.make_records([i.name for i in chunk], mu, sigma, sources), strict=True
            ):
                if decoder is not None and brdf is not None:
                    record = measure(record, decoder, brdf)
                    relae = record.meta.get("relae")
                    lines.append(
                        f"  {item.name:<32} RelAE mapped {relae['mapped']:.4f}  linear {relae['linear']:.4f}"
                        if relae else f"  {item.name:<32} (RelAE undefined: the material reflects nothing)"
                    )
                else:
                    why = "--no-measure" if decoder is None else "no source table"
                    lines.append(f"  {item.name:<32} (RelAE not measured: {why})")
                records.append(record)
            bar.update(len(chunk))
    dtype = "float16" if args.float16 else "float32"
    size = write_bvae(args.output, records, encoder.reference, latent_dtype=dtype, overwrite=args.force)
    print("\n".join(lines))
    measured = [r.meta["relae"]["mapped"] for r in records if "relae" in r.meta]
    if measured:
        print(f"  mean RelAE (mapped) over {len(measured)} materials: {np.mean(measured):.4f}")
    print(
        f"wrote {args.output}: {len(records)} material{'s' if len(records) != 1 else ''}, {size:,} bytes "
        f"({size / len(records):.1f} bytes per material; latents {dtype}; decoder {encoder.manifest.name} "
        f"{encoder.reference.sha256[:12]}…)"
    )
    return 0
