"""Short references (format 2.6, ``spec/bvae-format.md`` §3.1): a file names its decoder and its shared basis by the
first 8 bytes of their SHA-256, 48 bytes less a file with basis layers, and decodes exactly as with full hashes."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

import brdfcodec as bc
from brdfcodec import errors
from brdfcodec.cli import main
from brdfcodec.format.bvae import (
    FLAG_SHORT_REFERENCES,
    DecoderReference,
    LatentRecord,
    encode_bvae,
    parse_bvae,
)
from brdfcodec.format.layered_record import LayeredRecord
from brdfcodec.io.hashing import refers_to
from brdfcodec.io.merl import MerlBRDF, write_merl
from brdfcodec.layers.basis_layer import BasisLayer
from brdfcodec.layers.basis_storage import model_basis_lookup
from brdfcodec.models import registry

DECODER = DecoderReference("ab" * 32, "test")


def _flags(data: bytes) -> int:
    return int.from_bytes(data[12:16], "little")


@pytest.fixture(scope="module")
def gold(analytic_tables: dict[str, MerlBRDF]) -> MerlBRDF:
    return analytic_tables["gold"]


def test_short_references_save_48_bytes_and_decode_the_same(gold: MerlBRDF) -> None:
    short = bc.encode([gold], measure_error=False, bytes=32)
    full = bc.encode([gold], measure_error=False, bytes=32, short_references=False)
    assert len(full) - len(short) == 48  # a decoder and a basis hash, 24 bytes each
    assert short[8:12] == bytes([2, 0, 6, 0]) and _flags(short) & FLAG_SHORT_REFERENCES
    assert full[10] < 6 and not _flags(full) & FLAG_SHORT_REFERENCES  # readable by 2.5 readers, as before
    a, b = bc.decode(short), bc.decode(full)
    assert len(a.header.decoder.sha256) == 16 and b.header.decoder.matches(a.decoder.reference.sha256)
    assert a.header.decoder.matches(b.header.decoder.sha256)
    assert b.header.basis_sha256.startswith(a.header.basis_sha256) and len(a.header.basis_sha256) == 16
    np.testing.assert_array_equal(a["gold"].table(), b["gold"].table())


def test_a_file_without_basis_layers_saves_24_bytes(gold: MerlBRDF, tmp_path: Path) -> None:
    short = bc.encode([gold], measure_error=False)
    full = bc.encode([gold], measure_error=False, short_references=False)
    assert len(full) - len(short) == 24 and parse_bvae(short).header.basis_sha256 is None
    assert bc.compress([gold], tmp_path / "full.bvae", measure_error=False, short_references=False) == len(full)
    assert (tmp_path / "full.bvae").read_bytes() == full


def test_a_short_reference_is_written_short_and_never_widened() -> None:
    record = LatentRecord("a", np.zeros(8, np.float32), np.ones(8, np.float32))
    short = encode_bvae([record], DECODER.shortened())
    assert parse_bvae(short).header.decoder.sha256 == "ab" * 8 and short[10] == 6
    with pytest.raises(ValueError, match="full references cannot be written"):
        encode_bvae([record], DECODER.shortened(), short_references=False)
    layer = BasisLayer("cd" * 8, 0.5, np.array([3, -1], dtype=np.int8))
    layered = LayeredRecord("b", np.zeros(8, np.float32), np.ones(8, np.float32), basis=layer)
    with pytest.raises(ValueError, match="cdcdcdcdcdcdcdcd is a short reference"):
        encode_bvae([layered], DECODER, short_references=False)
    data = encode_bvae([layered], DECODER)  # a record read from a 2.6 file: written short, decoder included
    header = parse_bvae(data).header
    assert (header.decoder.sha256, header.basis_sha256) == ("ab" * 8, "cd" * 8)
    # one basis, named in full by one record and short by another: the same basis once shortened
    full_layer = dataclasses.replace(layered, name="c", basis=BasisLayer("cd" * 32, 0.5, np.array([1], np.int8)))
    assert parse_bvae(encode_bvae([layered, full_layer], DECODER)).header.basis_sha256 == "cd" * 8


def test_references_match_by_their_leading_bytes_only() -> None:
    full = "0123456789abcdef" + "0" * 48
    assert refers_to(full[:16], full) and refers_to(full, full)
    assert not refers_to(full[:16], "f" + full[1:]) and not refers_to(full[:15] + "e", full)
    assert not refers_to(full[:16], full[:16])  # a short reference names a full hash, not another reference
    with pytest.raises(ValueError, match="64 lower-case hex digits"):
        DecoderReference("ab" * 4, "eight hex digits are neither form")


def test_a_decoder_the_short_reference_does_not_name_is_refused(gold: MerlBRDF) -> None:
    data = bytearray(bc.encode([gold], measure_error=False))
    decoder = bc.BrdfDecoder()
    assert bc.decode(bytes(data), decoder=decoder)["gold"] is not None
    data[24] ^= 0xFF  # the reference's first byte, the header CRC mended below
    import zlib

    data[20:24] = zlib.crc32(bytes(data[24 : 24 + int.from_bytes(data[16:20], "little")]),
                             zlib.crc32(bytes(data[:20]))).to_bytes(4, "little")
    with pytest.raises(errors.DecoderMismatchError, match="the file needs decoder"):
        bc.decode(bytes(data), decoder=decoder)
    with pytest.raises(errors.ModelNotFoundError, match=f"no decoder with SHA-256 {bytes(data[24:32]).hex()}"):
        bc.decode(bytes(data))


def test_a_short_reference_that_names_two_installed_decoders_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    shipped = registry.find_model(bc.BrdfDecoder().reference.sha256)
    assert bc.BrdfDecoder(shipped.decoder_sha256[:16]).reference.sha256 == shipped.decoder_sha256  # as info prints
    twins = [dataclasses.replace(shipped, decoder_sha256="0123456789abcdef" + tail * 48) for tail in "01"]
    monkeypatch.setattr(registry, "_usable_models", lambda: iter(twins))
    assert registry.find_model(twins[1].decoder_sha256) is twins[1]  # a full hash is never ambiguous
    with pytest.raises(errors.ModelNotFoundError, match="names 2 installed decoders"):
        registry.find_model("0123456789abcdef")
    monkeypatch.setattr(registry, "_usable_models", lambda: iter([twins[0], twins[0]]))  # one model, two folders
    assert registry.find_model("0123456789abcdef") is twins[0]


def test_the_basis_is_found_by_its_short_reference_and_an_ambiguous_one_is_not() -> None:
    decoder = bc.BrdfDecoder()
    basis = decoder.shared_basis
    assert basis is not None
    found = decoder.basis_named(basis.sha256[:16])
    assert found is basis and found.sha256 == basis.sha256  # named by its full hash in memory
    assert decoder.basis_named("f" * 16) is None
    earlier = "e" * 64  # an earlier basis this one extends (spec/model.md §5): its first 10 vectors
    twin = basis.sha256[:16] + ("0" * 48 if basis.sha256[16] != "0" else "1" * 48)
    manifest = dataclasses.replace(decoder.manifest, basis_prefixes={earlier: 10, twin: 12})
    object.__setattr__(decoder, "manifest", manifest)
    leading = decoder.basis_named("e" * 16)
    assert leading is not None and leading.count == 10 and leading.sha256 == earlier
    assert decoder.basis_named(basis.sha256[:16]) is None  # names both the basis and an earlier one: refused
    assert decoder.basis_named(basis.sha256) is basis
    lookup = model_basis_lookup(manifest.folder, basis.sha256, manifest.basis_prefixes)  # bvae info's, no torch
    assert lookup(basis.sha256[:16]) is None and lookup(basis.sha256).sha256 == basis.sha256
    assert lookup("e" * 16).count == 10 and lookup("e" * 16).sha256 == earlier
    record = LayeredRecord("gold", np.zeros(8, np.float32), np.ones(8, np.float32),
                           basis=BasisLayer(basis.sha256[:16], 0.5, np.array([3, -1], dtype=np.int8)))
    with pytest.raises(errors.BasisMismatchError, match="a short reference: none of the model's bases, or two"):
        decoder.decode(record)


def test_cli_writes_short_references_unless_asked_and_edits_keep_them(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, gold: MerlBRDF) -> None:
    source = tmp_path / "gold.binary"
    write_merl(source, gold)
    short, full = tmp_path / "short.bvae", tmp_path / "full.bvae"
    assert main(["compress", str(source), "-o", str(short), "--bytes", "32", "--no-measure"]) == 0
    assert main(["compress", str(source), "-o", str(full), "--bytes", "32", "--no-measure",
                 "--full-references"]) == 0
    assert full.stat().st_size - short.stat().st_size == 48
    capsys.readouterr()
    assert main(["info", str(short)]) == 0
    out = capsys.readouterr().out
    assert "format 2.6" in out and out.count("short reference") == 2
    assert main(["info", "--json", str(short)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert len(summary["decoder"]["sha256"]) == 16 and summary["decoder"]["installed_at"]
    edited = tmp_path / "edited.bvae"
    assert main(["edit", "traverse", str(short), "-o", str(edited), "--dim", "1", "--values", "1"]) == 0
    assert _flags(edited.read_bytes()) & FLAG_SHORT_REFERENCES
    mixed = tmp_path / "mixed.bvae"  # operands from a full-hash file of the same decoder are accepted
    assert main(["edit", "interp", str(short), "gold", f"{full}:gold", "-o", str(mixed)]) == 0
    assert _flags(mixed.read_bytes()) & FLAG_SHORT_REFERENCES
