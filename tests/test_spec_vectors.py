"""The conformance vectors of spec/bvae-format.md §9: every valid file reads as listed, every invalid one
raises exactly the error class listed, the reference latents decode to the pinned values, and the generator
reproduces the committed files."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from script_loading import load_script

from brdfcodec import errors
from brdfcodec.format.bvae import FLAG_METADATA_ZSTD, FORMAT_MAJOR, FORMAT_MINOR, GraftRecord, parse_bvae

VECTORS = Path(__file__).resolve().parents[1] / "spec" / "vectors"
MANIFEST: dict[str, Any] = json.loads((VECTORS / "manifest.json").read_text(encoding="utf-8"))
ERROR_CLASSES = {key: getattr(errors, name) for key, name in MANIFEST["error_classes"].items()}


def _load_generator() -> Any:
    return load_script(VECTORS / "make_vectors.py")


def test_manifest_covers_what_the_spec_asks_for() -> None:
    valid = {Path(v["file"]).stem for v in MANIFEST["valid"]}
    assert {"one-material", "library", "float16", "graft", "compressed-header", "layered", "metadata-empty"} <= valid
    assert {v["error"] for v in MANIFEST["invalid"]} == set(ERROR_CLASSES)
    assert len(MANIFEST["invalid"]) >= 80
    invalid = {Path(v["file"]).stem for v in MANIFEST["invalid"]}
    # The rules of the binary header and index (2.0), the either-way ones of §9 included ...
    assert {"major-version-1", "major-version-3", "unknown-kind", "unknown-dtype", "header-ends-in-form-table",
            "form-unused", "form-twice", "form-index", "varint-not-minimal", "varint-too-long", "basis-unused",
            "basis-without-hash", "name-not-utf8", "record-crc"} <= invalid
    # ... the metadata block's (§5) ...
    assert {"metadata-unknown-name", "metadata-name-case", "zstd-flag-without-metadata", "meta-effort-string",
            "meta-effort-range", "meta-rate-number", "meta-source-kind-number", "header-amplification"} <= invalid
    # ... and those of layered records, the basis layer, compact mu and sigma, and the projected base.
    assert {"layered-unknown-detail-form", "layered-unknown-layer", "layered-no-layer", "layered-content-size",
            "basis-unknown-sigma", "basis-count-zero", "basis-count-payload", "basis-step-nan", "basis-step-zero",
            "basis-first-range", "basis-project-range", "compact-mu-unknown", "compact-mu-step-nan",
            "compact-sigma-length", "compact-mu-fixed-with-step"} <= invalid
    # Records without a latent (2.1): the pairing of mu and sigma "none", the basis layer they need, no projection.
    assert {"basis-only-sigma-with-mu", "basis-only-mu-with-sigma", "basis-only-no-basis", "basis-only-projected",
            "basis-only-unknown-sigma"} <= invalid
    # Packed basis layers (2.3): the padding, the widths the count needs, the top width, the layer bit's pairing.
    assert {"packed-padding-bits", "packed-too-many", "packed-top-zero", "packed-top-range", "packed-without-basis",
            "packed-short"} <= invalid
    # Entropy-coded basis layers (2.4): the shortest coding, the escape's bound, the layer bits' pairing, the length.
    assert {"coded-trailing-zero", "coded-escape-prefix", "coded-and-packed", "coded-without-basis",
            "coded-length-zero"} <= invalid
    assert {"basis-only", "version-2.0", "packed-basis", "coded-basis"} <= valid
    # Short references (2.6): a file that names the shipped decoder and basis by 8 bytes decodes; misread fields fail.
    assert "reference-decode-short" in valid
    assert {"short-references-over-full-hashes", "short-references-truncated", "unknown-flag"} <= invalid
    # Form variants (2.7): a valid table of variants (one of a variant); a base that is not an earlier layered form,
    # a changes byte naming nothing, a reserved bit or a field the base lacks, the same form twice, a range.
    assert "form-variants" in valid
    assert {"variant-base-later", "variant-base-latent", "variant-no-change", "variant-reserved-bit",
            "variant-absent-field", "variant-same-as-base", "variant-first-range"} <= invalid
    without = [r for v in MANIFEST["valid"] for r in v["records"] if r.get("layers", {}).get("mu") == "none"]
    assert len(without) == 6 and all(r["mu"] is None and r["layers"]["sigma"] == "none" for r in without)
    assert {"reference.basis-only", "reference.basis-only-detail"} <= set(MANIFEST["decode_layers"]["values"])
    projected = [r for v in MANIFEST["valid"] for r in v["records"]
                 if "project" in r.get("layers", {}).get("basis", {})]
    assert len(projected) == 3 and all(r["layers"]["basis"]["project"] == 50 for r in projected)
    compact = [r for v in MANIFEST["valid"] for r in v["records"] if r.get("layers", {}).get("mu") == "int8"]
    assert len(compact) == 2 and all(r["layers"]["sigma"] == "log2-u8-shared" for r in compact)
    assert MANIFEST["decode"]["values"] and MANIFEST["decode"]["rtol"] == 1e-3
    assert MANIFEST["decode_layers"]["values"]
    layers_file = next(v for v in MANIFEST["valid"] if v["file"] == MANIFEST["decode_layers"]["file"])
    assert layers_file["basis_sha256"] == MANIFEST["decode_layers"]["basis_sha256"]  # one basis per file


@pytest.mark.parametrize("vector", MANIFEST["valid"], ids=lambda v: Path(v["file"]).stem)
def test_valid_vector_reads_as_listed(vector: dict[str, Any]) -> None:
    parsed = parse_bvae((VECTORS / vector["file"]).read_bytes(), vector["file"])
    header = parsed.header
    assert (FORMAT_MAJOR, FORMAT_MINOR) == (2, 7) and MANIFEST["format_version"] == "2.7"
    assert f"{header.major}.{header.minor}" == vector["format_version"]  # the lowest version that holds the file
    assert header.decoder.sha256 == vector["decoder_sha256"]
    assert header.basis_sha256 == vector["basis_sha256"]
    assert header.latent_dtype == vector["latent_dtype"]
    assert bool(header.flags & FLAG_METADATA_ZSTD) == vector["header_compressed"]
    assert len(parsed.records) == len(vector["records"])
    for record, expected in zip(parsed.records, vector["records"], strict=True):
        assert record.name == expected["name"] and record.kind == expected["kind"]
        if expected["mu"] is None:  # a record without a latent (2.1, §4.6): neither mu nor sigma
            assert expected["sigma"] is None and not record.has_latent  # type: ignore[union-attr]
        else:
            np.testing.assert_array_equal(record.mu, np.float32(expected["mu"]))
            np.testing.assert_array_equal(record.sigma, np.float32(expected["sigma"]))
        assert dict(record.meta) == expected["meta"]
        if isinstance(record, GraftRecord):
            assert list(record.graft_dims) == expected["graft_dims"]
            np.testing.assert_array_equal(record.graft_values, np.float32(expected["graft_values"]))
        if record.kind == "layered":
            from brdfcodec.format.layered_record import layers_entry

            assert layers_entry(record) == expected["layers"]  # type: ignore[arg-type]
        else:
            assert "layers" not in expected


@pytest.mark.parametrize(
    "vector", [v for v in MANIFEST["invalid"] if v.get("when") != "decode"], ids=lambda v: Path(v["file"]).stem
)
def test_invalid_vector_raises_exactly_its_class(vector: dict[str, Any]) -> None:
    path = VECTORS / vector["file"]
    with pytest.raises(errors.BvaeFormatError) as caught:
        parse_bvae(path.read_bytes(), path)
    # Exactly the listed class: a checksum error is not reported as "unsupported", nor the reverse (§7).
    assert type(caught.value) is ERROR_CLASSES[vector["error"]], (vector["why"], caught.value)
    assert str(path) in str(caught.value)


def test_latent_size_mismatch_is_refused_when_opened_for_decoding() -> None:
    from brdfcodec.codec import MaterialLibrary

    (vector,) = [v for v in MANIFEST["invalid"] if v.get("when") == "decode"]
    path = VECTORS / vector["file"]
    parse_bvae(path.read_bytes())  # well-formed bytes
    with pytest.raises(errors.LatentDimensionError, match="latent_dim 4") as caught:
        MaterialLibrary(path)
    assert str(path) in str(caught.value)


@pytest.mark.parametrize("section", ["decode", "decode_layers", "decode_edits", "decode_short"])
def test_reference_latents_decode_to_the_pinned_values(section: str) -> None:
    from brdfcodec.codec import MaterialLibrary

    decode = MANIFEST[section]
    entries = [tuple(e) for e in decode["entries"]]
    with MaterialLibrary(VECTORS / decode["file"]) as library:
        for name, expected in decode["values"].items():
            table = library[name].table()
            got = np.array([table[e] for e in entries], dtype=np.float64)
            np.testing.assert_allclose(got, expected, rtol=decode["rtol"], atol=decode["atol"], err_msg=name)
    assert any(v == -1.0 for values in decode["values"].values() for v in values), "a masked entry is listed"


def test_generator_reproduces_the_committed_vectors(tmp_path: Path) -> None:
    generated = _load_generator().generate(tmp_path, with_reference=False)
    committed = dict(MANIFEST, decode={})
    committed.pop("decode_layers")
    committed.pop("decode_edits")  # decoded with the shipped model, as decode is
    committed.pop("decode_short")
    assert generated == committed
    for vector in [*MANIFEST["valid"], *MANIFEST["invalid"]]:
        new, old = (tmp_path / vector["file"]).read_bytes(), (VECTORS / vector["file"]).read_bytes()
        if new != old:
            # zstandard output may differ between library versions; the content may not.
            assert vector["file"] in {"valid/compressed-header.bvae", "invalid/zstd-trailing-bytes.bvae",
                                      "invalid/zstd-two-frames.bvae", "invalid/header-amplification.bvae"}, vector
