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
    # --- issue 14: refinement and rate control (brdfcodec.layers)
    parser.add_argument("--effort", type=int, choices=(0, 1, 2, 3), default=1,
                        help="latent refinement at encode time: 0 (encoder only) to 3 (slowest); default 1")
    target = parser.add_mutually_exclusive_group()
    target.add_argument("--bytes", type=int, metavar="N",
                        help="largest quality within N bytes of record payload per material (adds a detail layer)")
    target.add_argument("--max-relae", type=float, metavar="X",
                        help="smallest record whose measured RelAE on its material is at most X (adds a detail layer)")
    parser.add_argument("--metric", choices=("mapped", "linear"), default="mapped",
                        help="RelAE used by --max-relae (default mapped)")
    parser.set_defaults(handler=run)


def _merl_item(path: Path) -> _Item:
    def load() -> tuple[MerlBRDF | None, np.ndarray]:
        brdf = read_merl(path)
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


def _input_mask(brdf: MerlBRDF | None) -> np.ndarray:
    """Valid entries of a material's network input: from its table, else the horizon alone."""
    if brdf is not None:
        return material_arrays(brdf)[1]
    from brdfcodec.mask import kept_slice_horizon_mask
    from brdfcodec.transforms import network_input

    return network_input(np.repeat(kept_slice_horizon_mask()[None], 3, axis=0))


def run(args: argparse.Namespace) -> int:
    """Encode every input, write the file, print per-material RelAE and sizes."""
    from brdfcodec.codec import BrdfEncoder, measure

    if args.batch_size < 1:
        raise ValueError("--batch-size must be at least 1")
    check_output_path(args.output, overwrite=args.force)
    if args.output.suffix != ".bvae":
        raise ValueError(f"{args.output}: the output must end in .bvae")
    items = collect_items(args.inputs, args.split)
    dtype = "float16" if args.float16 else "float32"
    if args.bytes is not None and args.bytes < 1:
        raise ValueError("--bytes must be a positive number of bytes")
    encoder = BrdfEncoder(
        args.model, effort=args.effort, bytes=args.bytes, max_relae=args.max_relae, metric=args.metric,
        latent_dtype=dtype,
    )
    decoder = None if args.no_measure else encoder.decoder
    records: list[Record] = []
    lines: list[str] = []
    with tqdm(total=len(items), desc="compress", unit="material", disable=len(items) < 2 or None) as bar:
        for start in range(0, len(items), args.batch_size):
            chunk = items[start : start + args.batch_size]
            loaded = [item.load() for item in chunk]
            sources = [brdf for brdf, _ in loaded]
            inputs = np.stack([x for _, x in loaded])
            masks = np.stack([_input_mask(brdf) for brdf in sources])
            encoded = encoder.encode_arrays([i.name for i in chunk], inputs, masks, sources)
            for item, brdf, record in zip(chunk, sources, encoded, strict=True):
                if decoder is not None and brdf is not None:
                    record = measure(record, decoder, brdf)
                    relae = record.meta["relae"]
                    lines.append(f"  {item.name:<32} RelAE mapped {relae['mapped']:.4f}  linear {relae['linear']:.4f}")
                else:
                    why = "--no-measure" if decoder is None else "no source table"
                    lines.append(f"  {item.name:<32} (RelAE not measured: {why})")
                records.append(record)
            bar.update(len(chunk))
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
