"""Regression tests of the defects found by the adversarial pass (issue 11) and the spec gaps of issue 15,
at library level (the command line has tests/test_cli_hardening.py)."""

from __future__ import annotations

import errno
import json
import os
import struct
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest
from bvae_bytes import bytes_writer

from brdfcodec.errors import BvaeChecksumError, BvaeFormatError, UnmeasuredMaterialError, UnsupportedVersionError
from brdfcodec.format.bvae import (
    MAX_RECORDS,
    DecoderReference,
    GraftRecord,
    LatentRecord,
    canonical_json,
    encode_bvae,
    parse_bvae,
    write_bvae,
)
from brdfcodec.format.material_names import check_material_name, material_file_path
from brdfcodec.io import atomic
from brdfcodec.io.atomic import atomic_output
from brdfcodec.io.merl import MerlBRDF

DECODER = DecoderReference("ab" * 32, "test-decoder")
VECTORS = Path(__file__).resolve().parents[1] / "spec" / "vectors"


def record(name: str = "a", meta: dict | None = None) -> LatentRecord:
    return LatentRecord(name, np.zeros(8), np.ones(8), meta or {})


PAYLOAD = np.array([0.0] * 8 + [1.0] * 8, dtype="<f4").tobytes()


def raw_file(stored: bytes, payload: bytes = PAYLOAD, *, flags: int = 0) -> bytes:
    """A file written by hand (no writer checks): preamble, header, payload, valid header CRC."""
    return bytes_writer.assemble(stored, payload, flags=flags)


def one_record_header(name: str = "a", payload: bytes = PAYLOAD, *, form: bytes | None = None,
                      metadata: bytes = b"") -> bytes:
    """The binary header (format 2.0) of one record of D = 8 (a latent record by default), by hand."""
    raw = name.encode("utf-8", "surrogatepass")
    form = bytes_writer.latent_form() if form is None else form
    return bytes_writer.header([form], [bytes_writer.descriptor(raw, 0)], payload, dim=8, decoder=DECODER.sha256,
                               metadata=metadata)


def one_record_file(name: str = "a", meta: object = None, **top: object) -> bytes:
    """A one-record file; ``meta`` (any JSON) as the record's metadata, ``top`` as metadata fields."""
    block = {**top, **({"records": {name: meta}} if meta is not None else {})}
    return raw_file(one_record_header(name, metadata=json.dumps(block).encode() if block else b""))


# --------------------------------------------------------------------------- 1, 4: names


@pytest.mark.parametrize(
    "name", ["../UP", "/tmp/ESCAPED", ".", "..", ".hidden", "a/b", "a\\b", "C:x", "a\x85b", "a\ud800", "cafe\u0301",
             "NUL", "nul.txt", " gold", "gold.", "", "x" * 256, "a\nb", "a\x7fb"],
)
def test_unsafe_material_names_are_refused_on_write_and_read(name: str) -> None:
    with pytest.raises(ValueError, match="material name"):
        record(name)
    data = one_record_file(name)
    with pytest.raises(BvaeFormatError, match="name|surrogate") as caught:
        parse_bvae(data)
    assert type(caught.value) is BvaeFormatError


@pytest.mark.parametrize("name", ["gold", "café", "Ölfarbe №2 ☀", "gold.z4+2", "a~b@0.5", "a+b", "x" * 240, "日本"])
def test_ordinary_names_stay_valid(name: str, tmp_path: Path) -> None:
    assert parse_bvae(encode_bvae([record(name)], DECODER)).header.names == [name]
    assert material_file_path(tmp_path, name, "binary").parent == tmp_path


def test_case_and_normalisation_twins_are_one_name() -> None:
    with pytest.raises(ValueError, match="ignoring case"):
        encode_bvae([record("Gold"), record("gold")], DECODER)
    with pytest.raises(ValueError, match="NFC"):
        record("cafe\u0301")  # the NFD twin of "café" is refused outright


def test_a_name_never_chooses_a_folder(tmp_path: Path) -> None:
    for bad in ("../UP", str(tmp_path / "ESCAPED"), ".."):
        with pytest.raises(ValueError):
            material_file_path(tmp_path / "out", bad, "binary")
    assert check_material_name("ok") == "ok"


# --------------------------------------------------------------------------- 2, 3: metadata types and values


@pytest.mark.parametrize(
    "meta",
    [{"relae": {"mapped": None}}, {"relae": {"mapped": "x"}}, {"relae": None}, {"relae": {"mapped": -1.0}},
     {"relae": {"mapped": True}}, {"source_sha256": 3}, {"encoder_sha256": "abc"}, {"edit": "traverse"},
     {"edit": {"op": 1}}],
)
def test_wrongly_typed_metadata_is_refused_on_read_and_write(meta: dict) -> None:
    with pytest.raises(BvaeFormatError, match="meta field"):
        parse_bvae(one_record_file(meta=meta))
    with pytest.raises(ValueError, match="meta field"):
        record(meta=meta)


@pytest.mark.parametrize("number", ["1e400", "1e999", "-1e309", "9007199254740992", "-9007199254740993"])
def test_overflowing_numbers_are_refused(number: str) -> None:
    stored = one_record_header(metadata=f'{{"records": {{"a": {{"x": {number}}}}}}}'.encode())
    with pytest.raises(BvaeFormatError, match="overflow|2\\^53"):
        parse_bvae(raw_file(stored))


def test_writer_refuses_what_json_cannot_carry() -> None:
    for meta in ({"x": float("inf")}, {"x": float("nan")}, {"x": 2**53}, {"x": "\ud800"}, {"x": object()}):
        with pytest.raises(ValueError):
            encode_bvae([record(meta=meta)], DECODER)


def test_duplicate_keys_are_refused() -> None:
    stored = one_record_header(metadata=b'{"records": {"a": {"x": 0, "x": 0}}}')
    with pytest.raises(BvaeFormatError, match="duplicate key"):
        parse_bvae(raw_file(stored))


def test_header_fields_the_spec_settles() -> None:
    with pytest.raises(BvaeFormatError, match="created_by"):
        parse_bvae(one_record_file(meta={}, created_by=3))
    with pytest.raises(BvaeFormatError, match="decoder_name"):
        parse_bvae(one_record_file(meta={}, decoder_name=["d"]))
    graft = np.array([0.0] * 8 + [1.0] * 8 + [0.5, 0.5], dtype="<f4").tobytes()
    with pytest.raises(BvaeFormatError, match="graft dimensions"):
        parse_bvae(raw_file(one_record_header("g", graft, form=bytes_writer.graft_form([0, 0])), graft))
    with pytest.raises(BvaeFormatError, match="does not hold"):
        parse_bvae(raw_file(one_record_header(metadata=b'{"records": {"b": {}}}')))


def test_flag_bit_flipped_by_corruption_is_a_checksum_error() -> None:
    data = bytearray(encode_bvae([record()], DECODER, compress_header=False))
    data[12] |= 0x08  # reserved flag bit (3; bit 2 is known since 2.6), CRC not updated: corruption
    with pytest.raises(BvaeChecksumError):
        parse_bvae(bytes(data))
    stored = bytes(data[24:-64])
    with pytest.raises(UnsupportedVersionError):  # the same flag under a valid CRC: a newer writer's feature
        parse_bvae(raw_file(stored, bytes(data[-64:]), flags=8))


def test_nan_mu_and_zero_sigma_are_malformed_not_checksum_errors() -> None:
    for values in ([np.nan] + [0.0] * 7 + [1.0] * 8, [0.0] * 8 + [0.0] + [1.0] * 7):
        payload = np.array(values, dtype="<f4").tobytes()
        with pytest.raises(BvaeFormatError) as caught:
            parse_bvae(raw_file(one_record_header(payload=payload), payload))
        assert type(caught.value) is BvaeFormatError


# --------------------------------------------------------------------------- 6, 11: header work and zstd frames


def test_header_amplification_is_refused_without_building_the_objects() -> None:
    data = (VECTORS / "invalid" / "header-amplification.bvae").read_bytes()
    assert len(data) < 1600
    tracemalloc.start()
    try:
        with pytest.raises(BvaeFormatError, match="JSON objects and arrays"):
            parse_bvae(data)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 80 * 2**20, f"peak {peak / 2**20:.0f} MiB"  # 16 MiB of text and its string-free copy


def test_zstd_header_must_be_one_frame_with_nothing_after_it() -> None:
    import zstandard

    data = encode_bvae([record(meta={"effort": 1})], DECODER, compress_header=True)
    length = struct.unpack_from("<I", data, 16)[0]
    stored, payload = data[24 : 24 + length], data[24 + length :]
    index = stored[: stored.index(b"\x28\xb5\x2f\xfd")]  # the metadata block: a zstandard frame after the index
    frame = stored[len(index) :]
    assert parse_bvae(raw_file(index + frame, payload, flags=1)).header.names == ["a"]
    text = zstandard.ZstdDecompressor().decompress(frame)
    for block in (frame + b"\0", frame + zstandard.ZstdCompressor().compress(b" "),
                  zstandard.ZstdCompressor(write_content_size=True).compress(text[:10])
                  + zstandard.ZstdCompressor(write_content_size=True).compress(text[10:])):
        with pytest.raises(BvaeFormatError, match="after the compressed metadata|not valid"):
            parse_bvae(raw_file(index + block, payload, flags=1))


# --------------------------------------------------------------------------- 8: linear work at the record limit


@pytest.mark.slow
def test_a_library_at_the_record_limit_is_written_and_read() -> None:
    """65,536 records round-trip (that it takes linear time is benchmarks/test_bench_record_limit.py's check)."""
    records = [record(f"m{i}", {"relae": {"mapped": 0.1, "linear": 0.2}}) for i in range(MAX_RECORDS)]
    data = encode_bvae(records, DECODER)  # took 89 s with the quadratic duplicate check
    library = parse_bvae(data)
    assert [library.record(f"m{i}").name for i in range(0, MAX_RECORDS, 997)] == [
        f"m{i}" for i in range(0, MAX_RECORDS, 997)
    ]


def test_lookups_by_name_use_the_index_not_a_scan() -> None:
    library = parse_bvae(encode_bvae([record(f"m{i}") for i in range(50)], DECODER))
    header = library.header
    assert header.positions["m42"] == 42 and header.entry("m42").name == "m42"
    with pytest.raises(KeyError, match="no material 'zz'"):
        header.entry("zz")
    object.__setattr__(header, "entries", _NoIteration(header.entries))
    assert header.entry("m7").name == "m7" and library.record("m9").name == "m9"


class _NoIteration(tuple):
    """A tuple that refuses iteration: lookups must index, not scan."""

    def __iter__(self):  # type: ignore[override]
        raise AssertionError("scanned the index")


# --------------------------------------------------------------------------- 9: no-overwrite race


def test_no_overwrite_is_atomic_even_if_the_file_appears_after_the_check(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "a.bvae"

    with pytest.raises(FileExistsError), atomic_output(target) as tmp:
        tmp.write_bytes(b"mine")
        target.write_bytes(b"theirs")  # another process won the race after our existence check
        monkeypatch.setattr(Path, "exists", lambda self: False)  # ... and no later check sees it
    monkeypatch.undo()
    assert target.read_bytes() == b"theirs"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bvae"]


def test_no_overwrite_without_hard_links_reserves_the_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def no_links(*args: object) -> None:
        raise OSError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(atomic.os, "link", no_links)
    write_bvae(tmp_path / "a.bvae", [record()], DECODER)
    assert parse_bvae((tmp_path / "a.bvae").read_bytes()).header.names == ["a"]
    with pytest.raises(FileExistsError):
        write_bvae(tmp_path / "a.bvae", [record("b")], DECODER)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bvae"]


def test_errors_about_the_temporary_file_name_the_output(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "out.bvae"
    with pytest.raises(OSError) as caught, atomic_output(target) as tmp:
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp))
    assert caught.value.filename == str(target)

    def refuse(*args: object, **kwargs: object) -> None:
        raise PermissionError(errno.EACCES, "Permission denied", str(tmp_path / ".out.bvae.x1.part"))

    monkeypatch.setattr(atomic.tempfile, "mkstemp", refuse)
    with pytest.raises(PermissionError) as caught:
        write_bvae(target, [record()], DECODER)
    assert caught.value.filename == str(target) and ".part" not in str(caught.value)


# --------------------------------------------------------------------------- 5: degenerate tables


def test_degenerate_tables_prepare_clearly() -> None:
    from brdfcodec.codec import ClampWarning, prepare_source

    black = MerlBRDF(np.zeros((3, 90, 90, 180)), name="black")
    assert prepare_source(black) is black  # a black material is a material
    with pytest.raises(UnmeasuredMaterialError, match="nothing to compress"):
        prepare_source(MerlBRDF(np.full((3, 90, 90, 180), -1.0), name="empty"))
    huge = MerlBRDF(np.full((3, 90, 90, 180), 1e30), name="huge")
    with pytest.warns(ClampWarning, match=r"3334290 of 3334290 measured entries .* clamped") as caught:
        clamped = prepare_source(huge)
    assert "by up to" in str(caught[0].message)
    assert clamped.sha256 == huge.sha256 and np.isfinite(clamped.values).all() and clamped.values.max() < 1e12
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        prepare_source(MerlBRDF(np.full((3, 90, 90, 180), 1e308), name="max"), warn=False)


# --------------------------------------------------------------------------- edits: provenance, numbering, sigma


def test_edited_records_carry_provenance_not_stale_measurements() -> None:
    from brdfcodec.edit import latent_edits as edit
    measured = {"relae": {"mapped": 0.05, "linear": 0.1}, "source_sha256": "cd" * 32, "encoder_sha256": "ef" * 32}
    a = LatentRecord("a", np.zeros(8), np.full(8, 0.1), measured)
    b = LatentRecord("b", np.ones(8), np.full(8, 0.4), measured)
    grafted = edit.graft(a, [0.5, -1.0], (3, 4))
    assert grafted.meta == {"edit": {"op": "graft", "source": "a"}}
    (step,) = edit.traverse(a, 3, [2.0])
    assert step.meta == {"edit": {"op": "traverse", "source": "a", "parameter": 4, "value": 2.0, "unit": "sigma"}}
    assert step.name == "a.z4+2"
    mixed = edit.mix_factors(a, b, [3, 4])
    assert mixed.meta["edit"]["parameters_from_a"] == [4, 5]
    np.testing.assert_allclose(mixed.sigma, [0.4, 0.4, 0.4, 0.1, 0.1, 0.4, 0.4, 0.4])
    half = edit.interpolate(a, b, 0.5)
    np.testing.assert_allclose(half.sigma, np.full(8, 0.2), rtol=1e-6)  # geometric: sqrt(0.1 * 0.4)
    assert (edit.interpolate(a, b, 3.0).sigma > 0).all()  # extrapolation keeps sigma > 0
    assert "relae" not in half.meta and "relae" not in mixed.meta
    assert isinstance(grafted, GraftRecord)


# --------------------------------------------------------------------------- canonical bytes (§3.1)


def test_canonical_json_is_the_form_the_spec_states() -> None:
    value = {"b": [1, 0.25, 1e-05, 1.5e16, -0.0, 1.0], "a": 'q"\\/\x7f\n\x01é😀', "c": {"z": True, "y": None}}
    assert canonical_json(value) == (
        '{"a":"q\\"\\\\/\x7f\\n\\u0001é😀","b":[1,0.25,1e-05,1.5e+16,-0.0,1.0],"c":{"y":null,"z":true}}'
    ).encode()


def test_equal_content_gives_equal_bytes() -> None:
    records = [record(f"m{i}", {"relae": {"mapped": i / 7, "linear": 0.5}}) for i in range(5)]
    assert encode_bvae(records, DECODER) == encode_bvae(list(records), DECODER)


# --------------------------------------------------------------------------- eval(wi, wo)


@pytest.mark.parametrize(
    ("wi", "match"),
    [([0.0, 0.0, 0.0], "zero"), ([np.nan, 0.0, 1.0], "NaN"), ([0.0, 1.0], "3-vectors"), ([np.inf, 0, 1], "NaN")],
)
def test_eval_refuses_directions_that_are_not_directions(wi: list[float], match: str) -> None:
    brdf = MerlBRDF(np.zeros((3, 90, 90, 180)), name="black")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=match):
            brdf.eval(wi, [0.0, 0.0, 1.0])
    assert brdf.eval([[0.0, 0.0, 2.0]], [0.0, 0.6, 0.8]).shape == (1, 3)


def test_existing_files_still_read() -> None:
    from brdfcodec.examples import example_library

    library = parse_bvae(Path(example_library()).read_bytes())
    assert (library.header.major, library.header.minor) == (2, 2) and len(library.records) == 90
    assert all("relae" in r.meta for r in library.records)  # the example keeps its provenance
    assert os.fspath(example_library()).endswith(".bvae")


def test_spec_states_the_bounds_the_reader_uses() -> None:
    from brdfcodec.format.bvae import MAX_HEADER_CONTAINERS, MAX_HEADER_DEPTH, MAX_JSON_INTEGER

    text = (Path(__file__).resolve().parents[1] / "spec" / "bvae-format.md").read_text(encoding="utf-8")
    assert f"at most **{MAX_HEADER_CONTAINERS:,}** objects and arrays" in text
    assert f"at most **{MAX_HEADER_DEPTH}** levels of nesting" in text
    assert MAX_JSON_INTEGER == 2**53 - 1 and "±(2⁵³ − 1)" in text


def test_every_public_name_of_the_package_resolves() -> None:
    """``brdfcodec.__all__`` (the lazily imported codec names included) names each object once, and each exists."""
    import brdfcodec
    from brdfcodec import codec

    assert len(brdfcodec.__all__) == len(set(brdfcodec.__all__))
    for name in brdfcodec.__all__:
        assert getattr(brdfcodec, name) is not None, name
    assert brdfcodec.ClampWarning is codec.ClampWarning and brdfcodec.prepare_source is codec.prepare_source


def test_an_interruption_right_after_the_temporary_file_is_made_leaves_nothing(tmp_path, monkeypatch) -> None:
    """A SIGTERM (an exception in the CLI) can land between creating the temporary file and writing it."""
    import brdfcodec.io.atomic as atomic

    class Interrupted(BaseException):
        pass

    real_close = os.close

    def close_then_interrupt(fd: int) -> None:
        real_close(fd)
        raise Interrupted

    monkeypatch.setattr(atomic.os, "close", close_then_interrupt)
    with pytest.raises(Interrupted), atomic.atomic_output(tmp_path / "x.bin"):
        pass
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []


def test_unfinished_outputs_are_removed_when_the_block_is_never_left(tmp_path) -> None:
    """An exception between the context manager's own steps can leave a block without its cleanup running (the
    generator stays suspended): the CLI then removes every unfinished temporary file itself."""
    from brdfcodec.io.atomic import atomic_output, remove_unfinished_outputs

    block = atomic_output(tmp_path / "x.bin")
    tmp = block.__enter__()
    tmp.write_bytes(b"half")
    assert remove_unfinished_outputs() == [str(tmp)]
    assert list(tmp_path.iterdir()) == [] and remove_unfinished_outputs() == []
    with atomic_output(tmp_path / "y.bin") as done:  # a finished block leaves nothing to remove
        done.write_bytes(b"whole")
    assert remove_unfinished_outputs() == [] and (tmp_path / "y.bin").read_bytes() == b"whole"


@pytest.mark.parametrize("exchange", [True, False], ids=["one-step-swap", "two-renames"])
def test_a_folder_is_replaced_whole_or_not_at_all(tmp_path, monkeypatch, exchange: bool) -> None:
    """atomic_folder(replace=True): the block works on a copy; success swaps it in whole (Linux's one-step swap,
    or two renames where the system has none), failure leaves the folder as it was; nothing stays beside it."""
    import sys

    from brdfcodec.io import atomic

    swaps: list[bool] = []
    real = atomic._exchange

    def exchange_or_not(first, second):  # noqa: ANN001, ANN202
        swaps.append(exchange and real(first, second))
        return swaps[-1]

    monkeypatch.setattr(atomic, "_exchange", exchange_or_not)
    folder = tmp_path / "model"
    folder.mkdir()
    (folder / "weights").write_bytes(b"old weights")
    (folder / "manifest").write_bytes(b"names old weights")
    with pytest.raises(RuntimeError), atomic.atomic_folder(folder, replace=True) as staging:
        assert (staging / "weights").read_bytes() == b"old weights"  # a copy of the folder
        (staging / "weights").write_bytes(b"new weights")
        raise RuntimeError("crash before the manifest")
    assert (folder / "weights").read_bytes() == b"old weights" and sorted(os.listdir(tmp_path)) == ["model"]
    with atomic.atomic_folder(folder, replace=True) as staging:
        (staging / "weights").write_bytes(b"new weights")
        (staging / "manifest").write_bytes(b"names new weights")
        assert (folder / "weights").read_bytes() == b"old weights"  # untouched until the block ends
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == {"weights": b"new weights",
                                                                  "manifest": b"names new weights"}
    assert sorted(os.listdir(tmp_path)) == ["model"]
    assert swaps == [exchange and sys.platform.startswith("linux")]  # the one-step swap where the system has it


def test_a_failed_second_rename_puts_the_old_folder_back(tmp_path, monkeypatch) -> None:
    from brdfcodec.io import atomic

    monkeypatch.setattr(atomic, "_exchange", lambda first, second: False)
    folder = tmp_path / "model"
    folder.mkdir()
    (folder / "weights").write_bytes(b"old")
    real_rename = os.rename
    calls: list[str] = []

    def rename(source, destination):  # noqa: ANN001, ANN202
        calls.append(os.path.basename(destination))
        if len(calls) == 2:  # the new folder onto the target's name: interrupted
            raise KeyboardInterrupt
        real_rename(source, destination)

    monkeypatch.setattr(atomic.os, "rename", rename)
    with pytest.raises(KeyboardInterrupt), atomic.atomic_folder(folder, replace=True) as staging:
        (staging / "weights").write_bytes(b"new")
    assert calls[1] == "model" and (folder / "weights").read_bytes() == b"old"
    assert sorted(os.listdir(tmp_path)) == ["model"]


def test_a_replaced_folder_keeps_its_mode_and_read_only_copies_are_removed(tmp_path) -> None:
    from brdfcodec.io.atomic import atomic_folder

    folder = tmp_path / "model"
    folder.mkdir()
    (folder / "sub").mkdir()
    (folder / "sub" / "weights").write_bytes(b"old")
    os.chmod(folder / "sub", 0o555)
    os.chmod(folder, 0o550)
    try:
        with atomic_folder(folder, replace=True) as staging:
            assert os.stat(staging).st_mode & 0o700 == 0o700  # writable by its owner while the block runs
            (staging / "manifest").write_bytes(b"new")
        assert oct(os.stat(folder).st_mode & 0o777) == oct(0o550)
        assert (folder / "manifest").read_bytes() == b"new" and (folder / "sub" / "weights").read_bytes() == b"old"
        assert sorted(os.listdir(tmp_path)) == ["model"]  # the old folder, read-only inside, removed
        with pytest.raises(RuntimeError), atomic_folder(folder, replace=True):
            raise RuntimeError("crash")
        assert sorted(os.listdir(tmp_path)) == ["model"]  # the read-only copy removed
    finally:
        os.chmod(folder, 0o750)
        os.chmod(folder / "sub", 0o750)


def test_a_new_folder_appears_whole_and_never_over_an_existing_one(tmp_path) -> None:
    from brdfcodec.io.atomic import atomic_folder, remove_unfinished_outputs

    with pytest.raises(FileExistsError):
        with atomic_folder(tmp_path / "new") as staging:
            (staging / "a").write_bytes(b"a")
            assert not (tmp_path / "new").exists()
            (tmp_path / "new").mkdir()  # another writer took the name meanwhile: an empty folder is not replaced
    assert os.listdir(tmp_path / "new") == [] and sorted(os.listdir(tmp_path)) == ["new"]
    with pytest.raises(FileExistsError):
        atomic_folder(tmp_path / "new").__enter__()
    with pytest.raises(NotADirectoryError):
        atomic_folder(tmp_path / "absent", replace=True).__enter__()
    block = atomic_folder(tmp_path / "later")
    staging = block.__enter__()
    (staging / "half").write_bytes(b"half")
    assert remove_unfinished_outputs() == [str(staging)]  # the CLI's cleanup on SIGTERM removes the folder too
    assert sorted(os.listdir(tmp_path)) == ["new"]


def test_a_folder_replaced_through_a_link_keeps_the_link(tmp_path) -> None:
    from brdfcodec.io.atomic import atomic_folder

    real = tmp_path / "store" / "model-1"
    real.mkdir(parents=True)
    (real / "weights").write_bytes(b"old")
    link = tmp_path / "model"
    link.symlink_to(real, target_is_directory=True)
    with atomic_folder(link, replace=True) as staging:
        (staging / "weights").write_bytes(b"new")
    assert link.is_symlink() and (real / "weights").read_bytes() == b"new"
    assert sorted(os.listdir(tmp_path)) == ["model", "store"] and os.listdir(tmp_path / "store") == ["model-1"]
