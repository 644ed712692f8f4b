"""Form variants (format 2.7, ``spec/bvae-format.md`` §3.2): a layered form written as an earlier form's index and
the fields in which it differs; written where the file has short references, read as the form it makes."""

from __future__ import annotations

import dataclasses
import struct
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from brdfcodec.errors import BvaeFormatError
from brdfcodec.format.bvae import DecoderReference, encode_bvae, parse_bvae
from brdfcodec.format.form_variants import best_variant, resolve_variant, split_layered_form, variant_bytes
from brdfcodec.format.layered_record import LayeredRecord
from brdfcodec.layers.basis_layer import BasisLayer
from brdfcodec.layers.packed import packed_step

DECODER = DecoderReference("ab" * 8, "test")
BASIS = "cd" * 8


def _record(name: str, *, grid: int = 3, prior: tuple[int, int] = (156, 28), first: int = 8,
            project: int = 0) -> LayeredRecord:
    mu = (np.round(np.random.default_rng(len(name)).normal(size=8) * 4) / 4).astype(np.float32)  # on 2^-2, 2^-3
    layer = BasisLayer(BASIS, packed_step(100), np.array([25, -17, 0, 9, -2, 1]), first, project, prior=prior)
    return LayeredRecord(name, mu, np.ones(8, np.float32), basis=layer, coded_mu=grid, store_sigma=False)


LIBRARY = [_record("base"), _record("grid", grid=2), _record("prior", prior=(188, 28)),
           _record("projected", grid=2, first=0, project=50)]


#: Where the form table's first entry starts in a file of short references with a basis: the preamble, the decoder
#: reference, latent_dim and latent_dtype, the basis reference, the form count.
TABLE = 24 + 8 + 3 + 8 + 1


def test_a_library_writes_its_forms_as_variants_and_reads_them_as_the_forms_they_make() -> None:
    variants = encode_bvae(LIBRARY, DECODER)
    full = encode_bvae(LIBRARY, DECODER, form_variants=False)
    read, reference = parse_bvae(variants), parse_bvae(full)
    assert (read.header.minor, reference.header.minor) == (7, 6)
    assert read.header.form_count == reference.header.form_count == 4
    # 9 bytes a coded-mu form in full; as variants 4 (the grid), 5 (the prior), 5 (first and project, a variant of
    # the variant before it)
    assert len(full) - len(variants) == 3 * 9 - (4 + 5 + 5)
    assert variants[TABLE : TABLE + 9] == full[TABLE : TABLE + 9]  # the first form in full
    assert variants[TABLE + 9 : TABLE + 23] == bytes([3, 0, 0x10, 2, 3, 0, 0x08, 188, 28, 3, 1, 0x03, 0, 50])
    for mine, theirs in zip(read.header.entries, reference.header.entries, strict=True):
        assert (mine.name, mine.layers, mine.length) == (theirs.name, theirs.layers, theirs.length)
    for mine, theirs in zip(read.records, reference.records, strict=True):
        np.testing.assert_array_equal(mine.mu, theirs.mu)
        assert (mine.coded_mu, mine.basis.first, mine.basis.project, mine.basis.prior) == (
            theirs.coded_mu, theirs.basis.first, theirs.basis.project, theirs.basis.prior)


def test_full_references_write_every_form_in_full_and_one_form_needs_no_variant() -> None:
    long_decoder = DecoderReference("ab" * 32, "test")
    records = [dataclasses.replace(r, basis=dataclasses.replace(r.basis, sha256="cd" * 32)) for r in LIBRARY]
    assert parse_bvae(encode_bvae(records, long_decoder)).header.minor == 5  # for readers before 2.6: no variant
    one = encode_bvae(LIBRARY[:1], DECODER)
    assert parse_bvae(one).header.minor == 6 and one == encode_bvae(LIBRARY[:1], DECODER, form_variants=False)


def test_best_variant_takes_the_fewest_bytes_the_first_on_a_tie_and_only_a_form_of_the_same_layout() -> None:
    base = bytes([2, 4, 3, 9, 8, 0, 156, 28, 3])
    grid = bytes([2, 4, 3, 9, 8, 0, 156, 28, 2])
    both = bytes([2, 4, 3, 9, 0, 50, 188, 28, 2])
    assert best_variant(grid, [base]) == bytes([3, 0, 0x10, 2])
    assert best_variant(grid, [base, base]) == bytes([3, 0, 0x10, 2])  # the first of equal bases
    assert best_variant(both, [base, grid]) == bytes([3, 1, 0x0B, 0, 50, 188, 28])  # 7 bytes: from the grid's form
    everything = bytes([2, 4, 3, 9, 1, 1, 1, 1, 1])  # every field changed: still a byte shorter
    assert best_variant(everything, [base]) == bytes([3, 0, 0x1B, 1, 1, 1, 1, 1])
    other_layout = bytes([2, 0, 3, 9, 8, 0, 156, 28])  # mu in latent_dtype: no mu step, another layout
    assert variant_bytes(other_layout, 0, base) is None and best_variant(other_layout, [base]) == other_layout
    assert variant_bytes(base, 0, base) is None  # nothing changes
    assert resolve_variant(grid, {"mu_step": bytes([3])}) == base
    assert split_layered_form(bytes([2, 0, 0, 3, 0x80, 0x01, 0, 1])) == (bytes([2, 0, 0, 3]), {
        "first": bytes([0x80, 0x01]), "project": bytes([0]), "detail": bytes([1])})
    with pytest.raises(ValueError, match="no mu_step"):
        resolve_variant(other_layout, {"mu_step": bytes([2])})


def test_variants_can_be_asked_for_beside_full_references_and_left_out_beside_short_ones() -> None:
    long_decoder = DecoderReference("ab" * 32, "test")
    records = [dataclasses.replace(r, basis=dataclasses.replace(r.basis, sha256="cd" * 32)) for r in LIBRARY]
    assert parse_bvae(encode_bvae(records, long_decoder, form_variants=True)).header.minor == 7
    assert parse_bvae(encode_bvae(LIBRARY, DECODER, form_variants=False)).header.minor == 6


def _hand_made(forms: list[bytes], *, header_ends_after_forms: bool = False) -> bytes:
    """A file by hand (D = 2, full references): the forms, then one record per form, each an int8 basis layer of 3
    coefficients; or a header that ends right after the form table."""
    payload = (np.array([0.5, -1.0], "<f4").tobytes() + bytes([160, 176]) + np.float16(0.25).tobytes()
               + bytes([3, 253, 0]))
    stored = (bytes.fromhex("ab" * 32) + struct.pack("<HB", 2, 0) + bytes.fromhex("cd" * 32) + bytes([len(forms)])
              + b"".join(forms))
    data = b""
    if not header_ends_after_forms:
        count = len(forms)
        stored += bytes([count]) if count < 128 else bytes([count & 0x7F | 0x80, count >> 7])
        for i in range(count):
            name = f"m{i:03d}".encode()
            stored += bytes([len(name)]) + name + bytes([i, 3])
        data = payload * count
        stored += struct.pack("<I", zlib.crc32(data))
    head = b"\x89BVAE\r\n\x1a" + struct.pack("<HHII", 2, 7, 2, len(stored))
    return head + struct.pack("<I", zlib.crc32(stored, zlib.crc32(head))) + stored + data


def _int8_form(first: int) -> bytes:
    """A layered form: μ float32, σ log2-u8, an int8 basis layer from vector ``first``, not projected."""
    varint = bytes([first]) if first < 128 else bytes([first & 0x7F | 0x80, first >> 7])
    return bytes([2, 0, 1, 1]) + varint + b"\x00"


def test_a_variant_of_a_form_past_the_127th_names_its_base_in_two_bytes() -> None:
    forms = [_int8_form(i) for i in range(129)]
    forms.append(bytes([3, 0x80, 0x01, 0x01, 0xC8, 0x01]))  # form 129: form 128 with first = 200
    library = parse_bvae(_hand_made(forms))
    assert library.header.form_count == 130 and library.records[129].basis.first == 200
    assert library.records[128].basis.first == 128


@pytest.mark.parametrize(("variant", "cut", "message"), [
    (bytes([3, 0, 0x01]), True, "header ends inside record form 1's basis first"),
    (bytes([3, 0, 0x08]), False, "changes the prior of form 0, which has none"),
    (bytes([3, 0, 0x01, 0x85, 0x00]), False, "superfluous zero byte"),
    (bytes([3, 0, 0x02, 0x81, 0x20]), False, "projection is 4097"),  # checked on the form the variant makes
    (bytes([3, 0, 0x01, 0x00]), False, "sets the basis first of form 0 to the value it has"),
])
def test_a_broken_variant_is_refused_as_malformed_where_it_breaks(variant: bytes, cut: bool, message: str) -> None:
    data = _hand_made([_int8_form(0), variant], header_ends_after_forms=cut)
    with pytest.raises(BvaeFormatError, match=message):
        parse_bvae(data)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 13), st.integers(0, 255))
def test_any_byte_of_the_variants_under_a_valid_crc_is_read_or_refused_as_a_format_error(at: int, value: int) -> None:
    data = bytearray(encode_bvae(LIBRARY, DECODER))
    data[TABLE + 9 + at] = value  # a byte of the three variants after the first form
    length = struct.unpack_from("<I", data, 16)[0]
    data[20:24] = struct.pack("<I", zlib.crc32(bytes(data[24 : 24 + length]), zlib.crc32(bytes(data[:20]))))
    try:
        library = parse_bvae(bytes(data))
    except BvaeFormatError:
        return
    # What was accepted is a table the writer can state: its records written again read as the same entries.
    again = parse_bvae(encode_bvae(list(library.records), DECODER))
    assert [(e.name, e.layers) for e in again.header.entries] == [(e.name, e.layers) for e in library.header.entries]
