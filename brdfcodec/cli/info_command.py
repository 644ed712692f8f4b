"""``bvae info FILE...``: describe MERL tables, ``.bvae`` files and dataset files without decoding anything."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from brdfcodec.conventions import MERL_SHAPE
from brdfcodec.datasets.hdf5 import HDF5_SIGNATURE
from brdfcodec.errors import FileFormatError
from brdfcodec.format.bvae import FLAG_METADATA_ZSTD, RecordEntry, read_bvae
from brdfcodec.format.bvae import MAGIC as BVAE_MAGIC
from brdfcodec.format.material_names import shown_name
from brdfcodec.io.genuine import genuine_merl_name
from brdfcodec.io.merl import MERL_FILE_SIZE, read_merl
from brdfcodec.io.rgl import TENSOR_FILE_MAGIC
from brdfcodec.representation import reflectance_from_stored
from brdfcodec.representation.mask import horizon_mask

__all__ = ["HDF5_SIGNATURE", "describe_file", "register"]

_CHANNELS = ("red", "green", "blue")


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``info`` sub-command."""
    parser = subparsers.add_parser(
        "info",
        help="describe MERL .binary files, .bvae files and dataset files",
        description="Describe MERL .binary BRDF tables (dimensions, valid entries, per-channel "
        "range, whether it is a genuine MERL file), .bvae files (version, decoder and whether it is installed, "
        "materials, sizes) and brdfcodec dataset files. Nothing is decoded; a .bvae file is verified whole "
        "(header and every record's CRC-32 and values), as a decoder would.",
    )
    parser.add_argument("files", nargs="+", metavar="FILE", type=Path, help="files to describe")
    parser.add_argument("--json", action="store_true", help="print one JSON object per file")
    parser.set_defaults(handler=run)


def _merl_summary(path: Path) -> dict[str, Any]:
    brdf = read_merl(path)
    mask = brdf.mask
    physical = reflectance_from_stored(brdf.values)
    above = horizon_mask()
    channels = {}
    for c, label in enumerate(_CHANNELS):
        valid = physical[c][mask[c]]
        channels[label] = {
            "min": float(valid.min()) if valid.size else None,
            "median": float(np.median(valid)) if valid.size else None,
            "max": float(valid.max()) if valid.size else None,
        }
    sha = brdf.sha256
    return {
        "file": str(path),
        "kind": "merl",
        "dimensions": list(MERL_SHAPE),
        "bytes": MERL_FILE_SIZE,
        "sha256": sha,
        "genuine_merl": genuine_merl_name(sha),
        "valid_fraction": float(mask.mean()),
        "above_horizon_fraction": float(above.mean()),
        "unmeasured_above_horizon": int(np.count_nonzero(~mask & above[None])),
        "reflectance_per_sr": channels,
    }


def _dataset_summary(path: Path) -> dict[str, Any]:
    from brdfcodec.datasets.hdf5 import BrdfDataset

    with BrdfDataset(path) as dataset:
        return {
            "file": str(path),
            "kind": "dataset",
            "source_kind": dataset.source_kind,
            "description": dataset.description,
            "materials": len(dataset),
            "train": len(dataset.indices("train")),
            "validation": len(dataset.indices("validation")),
            "validation_names": [dataset.names[i] for i in dataset.indices("validation")],
            "full_tables": dataset.has_tables,
            "created": str(dataset.attribute("created")),
            "bytes": path.stat().st_size,
        }


def _bvae_summary(path: Path) -> dict[str, Any]:
    from brdfcodec.errors import DecoderNotFoundError, LatentDimensionError
    from brdfcodec.models.registry import find_model

    # Every record verified (CRC, finite values, sigma > 0), not only the header; the preamble is read first, then
    # only what the header declares (a device or a huge file that is not a .bvae file is refused at once).
    header = read_bvae(path).header
    try:
        model = find_model(header.decoder.sha256)
        installed: str | None = str(model.folder)
    except DecoderNotFoundError:
        installed = None
    else:  # §7 step 10, as opening the file for decoding does: the latent size (§6 rule 1), then the basis layers
        if header.latent_dim != model.config.latent_dim:
            raise LatentDimensionError(
                path, f"declares latent_dim {header.latent_dim}, but its decoder {model.name} "
                f"({header.decoder.sha256[:12]}…) has {model.config.latent_dim}: the file is inconsistent",
            )
        from brdfcodec.layers.basis import check_basis_layers, check_records_without_latent, model_basis_lookup

        bases = model_basis_lookup(model.folder, model.basis_sha256, model.basis_prefixes)
        check_basis_layers(header.entries, bases, str(path), model.basis_sha256)
        check_records_without_latent(header.entries, bases, str(path), bool(model.config.linear_basis))
    name = header.decoder.name or (model.name if installed is not None else "")
    materials = [_record_summary(entry, header.latent_dtype) for entry in header.entries]
    names = sum(len(entry.name.encode("utf-8")) for entry in header.entries)
    index = sum(entry.descriptor_bytes for entry in header.entries)
    return {
        "file": str(path),
        "kind": "bvae",
        "format_version": f"{header.major}.{header.minor}",
        "created_by": header.created_by,
        "decoder": {"sha256": header.decoder.sha256, "name": name, "installed_at": installed},
        "latent_dim": header.latent_dim,
        "latent_dtype": header.latent_dtype,
        "basis_sha256": header.basis_sha256,
        "record_forms": header.form_count,
        "metadata": any(entry.meta for entry in header.entries) or bool(header.created_by),
        "header_compressed": bool(header.flags & FLAG_METADATA_ZSTD),
        "header_bytes": header.header_bytes,
        "bytes": header.file_size,
        "bytes_per_material": header.file_size / len(header.entries),
        "names_bytes": names,
        "index_bytes": index,
        "payload_bytes": header.file_size - header.records_offset,
        "materials": materials,
    }


def _record_summary(entry: RecordEntry, latent_dtype: str) -> dict[str, Any]:
    """What one record stores (μ and σ forms, layers, sizes) and, when it carries them, its provenance."""
    layers = entry.layers or {}
    item: dict[str, Any] = {
        "name": entry.name, "kind": entry.kind,
        "mu": layers.get("mu", latent_dtype), "sigma": layers.get("sigma", latent_dtype),
        "latent": layers.get("mu") != "none",  # False: a basis-only record (format 2.1), which cannot be edited
        "payload_bytes": entry.length, "record_bytes": entry.length + entry.descriptor_bytes,
    }
    if entry.graft_dims:
        item["graft_dims"] = list(entry.graft_dims)
    if "mu_step" in layers.get("basis", {}):  # a coded μ (format 2.5): its grid 2^-g
        item["mu_step"] = layers["basis"]["mu_step"]
    if "basis" in layers:
        basis = layers["basis"]
        item["basis"] = {"count": basis["count"], "first": basis.get("first", 0), "project": basis.get("project", 0),
                         "packed_top": basis.get("top", 0)}
        if "prior" in basis:  # entropy-coded (format 2.4): the form's prior and the layer's bytes
            item["basis"].update({"coded_prior": list(basis["prior"]), "coded_bytes": basis["length"]})
    if "detail" in layers:
        item["detail_bytes"] = layers["detail"]["length"]
    item.update({k: v for k, v in entry.meta.items()
                 if k in ("relae", "source_sha256", "source_kind", "edit", "effort", "rate")})
    return item


def _stored_forms(item: dict[str, Any], latent_dtype: str) -> str:
    """One line of what a record stores: μ, σ, the layers."""
    mu = {"int8-fixed": "μ int8 grid", "int8": "μ int8+step",
          "coded": f"μ coded in the basis layer, grid 2^-{item.get('mu_step', '?')}"}.get(item["mu"], f"μ {item['mu']}")
    sigma = {"log2-u8": "σ u8", "log2-u8-shared": "σ shared u8"}.get(item["sigma"], f"σ {item['sigma']}")
    parts = [mu, sigma] if item["latent"] else ["latent: none (basis only)"]
    if item["kind"] == "graft":  # parameters numbered from 1, like every number the CLI shows
        parts.append("graft z" + ",".join(str(d + 1) for d in item["graft_dims"]))
    if "basis" in item:
        count, first, project = item["basis"]["count"], item["basis"]["first"], item["basis"]["project"]
        vectors = f"vector {first + 1}" if count == 1 else f"vectors {first + 1}–{first + count}"
        top = item["basis"].get("packed_top", 0)
        coded = item["basis"].get("coded_prior")
        how = f"; packed, top width {top}" if top else (f"; entropy-coded, prior {coded[0]}/{coded[1]}" if coded else "")
        parts.append(f"basis {count} ({vectors}{how})"
                     + (f", base projected on {project}" if project else ""))
    if "detail_bytes" in item:
        parts.append(f"detail {item['detail_bytes']:,} B")
    return ", ".join(parts)


def _rgl_summary(path: Path) -> dict[str, Any]:
    from brdfcodec.errors import SourceFormatError
    from brdfcodec.io.hashing import sha256_of_file
    from brdfcodec.io.rgl import check_supported, read_rgl_header

    header = read_rgl_header(path)
    try:
        check_supported(header)
        problem = None
    except SourceFormatError as error:
        problem = error.problem
    return {
        "file": str(path),
        "kind": "rgl",
        "description": header.description,
        "tensor_file_version": list(header.version),
        "bytes": path.stat().st_size,
        "sha256": sha256_of_file(path),
        "isotropic": header.isotropic,
        "colour": header.colour,
        "incident_elevations": header.theta_i_count,
        "fields": {name: list(field.shape) for name, field in header.fields.items()},
        "supported": problem is None,
        "unsupported_because": problem,
    }


def describe_file(path: Path) -> dict[str, Any]:
    """Summary of one file as a JSON-ready dictionary.

    Raises
    ------
    FileFormatError
        The file is neither a MERL table nor a dataset, or is malformed.
    """
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a directory, expected a file")
    with open(path, "rb") as stream:
        head = stream.read(8)
    if head == HDF5_SIGNATURE:
        return _dataset_summary(path)
    if head == BVAE_MAGIC or path.suffix == ".bvae":
        return _bvae_summary(path)
    if head == TENSOR_FILE_MAGIC[:8]:
        return _rgl_summary(path)
    size = os.path.getsize(path)
    if size < 12:
        raise FileFormatError(path, f"file is {size} bytes: neither a MERL .binary file nor a dataset")
    return _merl_summary(path)


def _format_text(summary: dict[str, Any]) -> str:
    lines = [summary["file"]]
    if summary["kind"] == "bvae":
        decoder = summary["decoder"]
        where = decoder["installed_at"] or "NOT INSTALLED: register the model folder that made this file"
        created = f" ({summary['created_by']})" if summary["created_by"] else ""
        rest = summary["header_bytes"] - summary["names_bytes"] - summary["index_bytes"]
        floats = sum(summary["latent_dtype"] in (item["mu"], item["sigma"]) for item in summary["materials"])
        metadata = "per-record metadata" if summary["metadata"] else "no metadata (names and records only)"
        basis = _reference(summary["basis_sha256"]) if summary["basis_sha256"] else "- (no basis layer)"
        lines += [
            f"  kind            .bvae latent file, format {summary['format_version']}{created}",
            f"  decoder         {decoder['name'] or '(name not stored)'}  sha256 {_reference(decoder['sha256'])}",
            f"                  {where}",
            f"  latents         {summary['latent_dim']} dimensions; {summary['latent_dtype']} where a record "
            f"stores μ or σ as floats ({floats} of {len(summary['materials'])}; per record below)",
            f"  shared basis    {basis}",
            f"  size            {summary['bytes']:,} bytes ({summary['bytes_per_material']:.1f} per material): "
            f"payloads {summary['payload_bytes']:,}, names {summary['names_bytes']:,}, index "
            f"{summary['index_bytes']:,}, rest of the header {rest:,}",
            f"  records         {len(summary['materials'])} in {summary['record_forms']} "
            f"form{'s' if summary['record_forms'] != 1 else ''}; {metadata}"
            f"{' (zstd)' if summary['header_compressed'] else ''}",
        ]
        for item in summary["materials"][:50]:
            relae = item.get("relae", {})
            notes = [f"RelAE {relae['mapped']:.4f}"] if isinstance(relae, dict) and "mapped" in relae else []
            if "source_kind" in item:
                notes.append(f"source {item['source_kind']}")
            kind = "" if item["kind"] == "latent" else f"[{item['kind']}] "
            lines.append(f"    {shown_name(item['name']):<32} {kind}{_stored_forms(item, summary['latent_dtype'])}; "
                         f"{item['payload_bytes']:,} B payload, {item['record_bytes']:,} B with its index entry  "
                         f"{'  '.join(notes)}".rstrip())
        if len(summary["materials"]) > 50:
            lines.append(f"    … and {len(summary['materials']) - 50} more (--json lists all)")
        return "\n".join(lines)
    if summary["kind"] == "dataset":
        lines += [
            f"  kind            brdfcodec dataset ({summary['source_kind']})",
            f"  data            {summary['description']}",
            f"  materials       {summary['materials']} ({summary['train']} train, "
            f"{summary['validation']} validation)",
            f"  validation      {', '.join(summary['validation_names']) or '-'}",
            f"  full tables     {'yes' if summary['full_tables'] else 'no'}",
            f"  created         {summary['created']}",
            f"  size            {summary['bytes']:,} bytes",
        ]
        return "\n".join(lines)
    if summary["kind"] == "rgl":
        support = "yes" if summary["supported"] else f"no: {summary['unsupported_because']}"
        lines += [
            "  kind            RGL .bsdf measurement (Mitsuba tensor file "
            f"{'.'.join(map(str, summary['tensor_file_version']))}, {summary['bytes']:,} bytes)",
            f"  material        {summary['description'] or '-'}",
            f"  sha256          {summary['sha256']}",
            f"  layout          {'isotropic' if summary['isotropic'] else 'anisotropic'}, {summary['colour']}, "
            f"{summary['incident_elevations']} incident elevations",
            f"  brdfcodec reads {support}",
        ]
        return "\n".join(lines)
    genuine = summary["genuine_merl"]
    lines += [
        "  kind            MERL .binary BRDF table "
        f"({' x '.join(map(str, summary['dimensions']))} RGB, float64, {summary['bytes']:,} bytes)",
        f"  sha256          {summary['sha256']}",
        "  genuine MERL    " + (f"yes: {genuine}" if genuine else "no (checksum not among the 100 published)"),
        f"  valid entries   {100 * summary['valid_fraction']:.2f} % "
        f"(above horizon {100 * summary['above_horizon_fraction']:.2f} %, "
        f"unmeasured above horizon: {summary['unmeasured_above_horizon']})",
        "  reflectance (1/sr, valid entries)   min          median       max",
    ]
    for label, stats in summary["reflectance_per_sr"].items():
        if stats["min"] is None:
            lines.append(f"    {label:<33} (no valid entry)")
        else:
            lines.append(f"    {label:<33} {stats['min']:<12.5g} {stats['median']:<12.5g} {stats['max']:.5g}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Describe each file; stops at the first bad one (its error names it)."""
    for index, path in enumerate(args.files):
        summary = describe_file(path)
        if args.json:
            print(json.dumps(summary, allow_nan=False))
        else:
            if index:
                print()
            print(_format_text(summary))
    return 0


def _reference(sha256: str) -> str:
    """A file's reference to a decoder or basis as ``bvae info`` prints it: a short one (format 2.6) says so."""
    return sha256 if len(sha256) == 64 else f"{sha256}… (short reference: the hash's first 8 bytes)"
