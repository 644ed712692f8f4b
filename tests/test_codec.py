"""The codec API: encode, decode (full, slices, query directions), libraries, grafts, decoder checks."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
import torch

from brdfcodec.codec import (
    BrdfDecoder,
    BrdfEncoder,
    MaterialInput,
    MaterialLibrary,
    compress,
    decode,
    decompress,
    encode,
    encode_records,
)
from brdfcodec.conventions import UNMEASURED_VALUE
from brdfcodec.errors import DecoderMismatchError, DecoderNotFoundError
from brdfcodec.format.bvae import (
    MAGIC,
    DecoderReference,
    GraftRecord,
    LatentRecord,
    parse_bvae,
    read_bvae,
    write_bvae,
)
from brdfcodec.io.merl import MerlBRDF, write_merl
from brdfcodec.models.registry import default_model_folder
from brdfcodec.representation import (
    map_values,
    network_input_from_table,
    reflectance_from_stored,
    table_from_network_output,
)
from brdfcodec.representation.mask import horizon_mask
from brdfcodec.representation.metrics import error_report


@pytest.fixture(scope="module")
def decoder(tiny_model_folder: Path) -> BrdfDecoder:
    return BrdfDecoder(tiny_model_folder)


@pytest.fixture(autouse=True)
def tiny_model_registered(tiny_model_folder: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BRDFCODEC_MODEL_PATH", str(tiny_model_folder))


def records(count: int, dim: int, seed: int = 0) -> list[LatentRecord]:
    rng = np.random.default_rng(seed)
    return [LatentRecord(f"m{i:03d}", rng.normal(size=dim), np.full(dim, 0.2)) for i in range(count)]


def assert_same_decode(a: np.ndarray, b: np.ndarray) -> None:
    """Equal up to floating-point summation order, compared in the mapped domain where the network rounds."""
    np.testing.assert_allclose(map_values(np.maximum(a, 0)), map_values(np.maximum(b, 0)), rtol=0, atol=2e-6)
    np.testing.assert_array_equal(a < 0, b < 0)


def read_merl_from_spec(path: Path) -> np.ndarray:
    """Independent MERL reader (spec/conventions.md §1): 3 int32 dims, then float64 R, G, B planes."""
    raw = path.read_bytes()
    dims = struct.unpack_from("<3i", raw, 0)
    assert dims == (90, 90, 180) and len(raw) == 12 + 8 * 3 * 90 * 90 * 180
    return np.frombuffer(raw, dtype="<f8", offset=12).reshape(3, 90, 90, 180)


def test_round_trip_is_bit_exact_and_follows_the_decoding_rules(decoder: BrdfDecoder, tmp_path: Path) -> None:
    record = records(1, decoder.latent_dim)[0]
    path = tmp_path / "one.bvae"
    write_bvae(path, [record], decoder.reference)
    decoded = decompress(path)
    with torch.inference_mode():
        mapped = decoder.network(torch.from_numpy(record.mu[None].copy())).numpy()[0]
    expected = table_from_network_output(mapped)
    above = np.broadcast_to(horizon_mask(), expected.shape)
    np.testing.assert_array_equal(decoded[above], expected[above])
    assert (decoded[~above] == UNMEASURED_VALUE).all()
    np.testing.assert_array_equal(decoded, decompress(path))  # deterministic
    merl_path = tmp_path / "one.binary"
    write_merl(merl_path, decoded.astype(np.float64))
    np.testing.assert_array_equal(read_merl_from_spec(merl_path), decoded.astype(np.float64))


def test_slices_equal_the_full_table(decoder: BrdfDecoder) -> None:
    rng = np.random.default_rng(3)
    graft = GraftRecord("g", rng.normal(size=decoder.latent_dim), np.ones(decoder.latent_dim), (0, 1), [2.0, -1.0])
    for record in (records(1, decoder.latent_dim)[0], graft):
        full = decoder.decode(record)
        for bins in ([0], [9], [90, 91], [179], [170, 175, 179], list(range(0, 180, 3))):
            part = decoder.decode(record, phi_d_bins=bins)
            assert_same_decode(part, full[..., bins])
    with pytest.raises(ValueError, match="phi_d_bins"):
        decoder.decode(graft, phi_d_bins=[180])


@pytest.mark.slow
def test_library_decodes_only_what_is_used(decoder: BrdfDecoder, tmp_path: Path) -> None:
    path = tmp_path / "lib.bvae"
    write_bvae(path, records(100, decoder.latent_dim), decoder.reference)
    with MaterialLibrary(path, decoder=decoder) as library:
        assert len(library) == 100 and "m042" in library
        for name in ("m001", "m042", "m099"):
            value = library[name].eval(np.array([0.0, 0.0, 1.0]), np.array([0.2, 0.1, 0.97]))
            assert value.shape == (3,) and np.isfinite(value).all() and (value >= 0).all()
        library["m042"].eval(np.array([0.0, 0.6, 0.8]), np.array([0.0, -0.6, 0.8]))
        assert library.decoded_count == 3
        one_slice = library["m050"].table(phi_d_bins=[90])
        assert one_slice.shape == (3, 90, 90, 1) and library.decoded_count == 3
    batch = list(decoder.decode_many(read_bvae(path).records[:5]))
    single = [decoder.decode(r) for r in read_bvae(path).records[:5]]
    for a, b in zip(batch, single, strict=True):
        assert_same_decode(a, b)


def test_eval_matches_the_decoded_table(decoder: BrdfDecoder, tmp_path: Path) -> None:
    path = tmp_path / "lib.bvae"
    write_bvae(path, records(1, decoder.latent_dim), decoder.reference)
    material = MaterialLibrary(path, decoder=decoder)["m000"]
    reflectance = material.reflectance()
    wi, wo = np.array([0.0, 0.0, 1.0]), np.array([np.sin(0.5), 0.0, np.cos(0.5)])
    from brdfcodec.representation.lookup import lookup

    np.testing.assert_allclose(material.eval(wi, wo), lookup(reflectance, wi, wo), rtol=1e-6)
    np.testing.assert_array_equal(material.eval(np.array([0, 0, 1.0]), np.array([1.0, 0, -0.1])), 0.0)
    assert material.to_merl().values.dtype == np.float64


def test_wrong_or_missing_decoder_is_refused(decoder: BrdfDecoder, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.delenv("BRDFCODEC_MODEL_PATH")
    other = tmp_path / "other.bvae"
    write_bvae(other, records(1, decoder.latent_dim), DecoderReference("0" * 64, "vanished-model"))
    with pytest.raises(DecoderNotFoundError, match="0{64}.*available: .*bvae-nbrdf-proxy-small-v1"):
        MaterialLibrary(other)
    default = BrdfDecoder()
    mine = tmp_path / "mine.bvae"
    write_bvae(mine, records(1, decoder.latent_dim), decoder.reference)
    with pytest.raises(DecoderMismatchError, match=f"{decoder.reference.sha256}.*{default.reference.sha256}"):
        MaterialLibrary(mine, decoder=default)


def test_decoder_is_found_by_hash_when_registered(decoder: BrdfDecoder, tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "x.bvae"
    write_bvae(path, records(1, decoder.latent_dim), decoder.reference)
    with MaterialLibrary(path) as library:
        assert library.decoder.reference == decoder.reference
    np.testing.assert_array_equal(BrdfDecoder(decoder.reference.sha256).decode(records(1, 8)[0]),
                                  decoder.decode(records(1, 8)[0]))


def test_graft_with_equal_codes_copies_red_into_green(decoder: BrdfDecoder) -> None:
    base = records(1, decoder.latent_dim, seed=5)[0]
    dims = (0, 3)
    graft = GraftRecord("g", base.mu, base.sigma, dims, base.mu[list(dims)])
    plain = decoder.decode(base, masked="zero")
    grafted = decoder.decode(graft, masked="zero")
    np.testing.assert_array_equal(grafted[0], plain[0])
    np.testing.assert_array_equal(grafted[2], plain[2])
    reflectance = reflectance_from_stored(grafted)
    np.testing.assert_allclose(reflectance[1], reflectance[0], rtol=1e-5, atol=1e-9)
    changed = GraftRecord("g2", base.mu, base.sigma, dims, base.mu[list(dims)] + 3.0)
    other = decoder.decode(changed, masked="zero")
    np.testing.assert_array_equal(other[0], plain[0])
    assert not np.allclose(other[1], grafted[1])


@pytest.mark.slow
def test_encode_and_decode_are_inverse_on_bytes(tiny_model_folder: Path, analytic_tables: dict[str, MerlBRDF],
                                                tmp_path: Path) -> None:
    gold, chrome = analytic_tables["gold"], analytic_tables["chrome"]
    data = encode([gold, chrome], names=["gold", "chrome"], model=tiny_model_folder, provenance=True)
    assert isinstance(data, bytes) and data.startswith(MAGIC)
    lean = parse_bvae(encode([gold, chrome], names=["gold", "chrome"], model=tiny_model_folder))
    assert all(not r.meta for r in lean.records) and lean.header.file_size < len(data)  # provenance is opt-in
    parsed = parse_bvae(data)
    encoder = BrdfEncoder(tiny_model_folder)
    # the decoder named by a short reference (format 2.6): its hash's first 8 bytes, its name in the metadata
    assert parsed.header.decoder == encoder.reference.shortened() and parsed.header.names == ["gold", "chrome"]
    batch = encoder.encode_many([gold, chrome])
    for stored, fresh, source in zip(parsed.records, batch, (gold, chrome), strict=True):
        np.testing.assert_allclose(stored.mu, fresh.mu, rtol=1e-5, atol=1e-6)
        assert stored.meta["source_sha256"] == source.sha256
    library = decode(data)
    decoder = BrdfDecoder(tiny_model_folder)
    for record, source in zip(parsed.records, (gold, chrome), strict=True):
        table = library[record.name].table()
        np.testing.assert_array_equal(table, decoder.decode(record))  # decode(bytes) is the decoder's table
        report = error_report(source.values, library[record.name].table(masked="keep").astype(np.float64), source.mask)
        assert record.meta["relae"] == {"mapped": report.relae_mapped.overall, "linear": report.relae_linear.overall}
    assert list(library) == ["gold", "chrome"] and library.path is None
    # The file helpers write exactly encode()'s bytes and read them back.
    size = compress([gold, chrome], tmp_path / "two.bvae", names=["gold", "chrome"], model=tiny_model_folder,
                    provenance=True)
    assert (tmp_path / "two.bvae").read_bytes() == data and size == len(data)
    with pytest.raises(FileExistsError):
        compress(gold, tmp_path / "two.bvae", model=tiny_model_folder)
    with pytest.raises(ValueError, match="holds 2 materials"):
        decompress(tmp_path / "two.bvae")
    np.testing.assert_array_equal(decompress(tmp_path / "two.bvae", "chrome"), library["chrome"].table())


def test_encode_records_streams_sources_in_batches(tiny_model_folder: Path,
                                                  analytic_tables: dict[str, MerlBRDF]) -> None:
    encoder = BrdfEncoder(tiny_model_folder)
    tables = list(analytic_tables.values())[:5]
    loaded: list[int] = []

    def lazily():
        for i, table in enumerate(tables):
            loaded.append(i)
            yield table

    seen: list[int] = []
    records = encode_records(lazily(), encoder=encoder, measure_error=False, batch_size=2,
                             on_batch=lambda batch: seen.append(len(batch)))
    assert seen == [2, 2, 1] and loaded == list(range(5))
    assert [r.name for r in records] == [t.name for t in tables] and all("relae" not in r.meta for r in records)
    inputs = MaterialInput("from-inputs", network_input_from_table(tables[0].values)[0])
    [record] = encode_records([inputs], encoder=encoder)  # no table: nothing to measure
    np.testing.assert_array_equal(record.mu, records[0].mu)
    assert "relae" not in record.meta and "source_sha256" not in record.meta


@pytest.mark.parametrize("scale", [10.0, 50.0])
def test_extreme_latents_decode_to_finite_non_negative_tables(scale: float) -> None:
    decoder = BrdfDecoder(default_model_folder())
    rng = np.random.default_rng(int(scale))
    for code in (rng.normal(size=(4, 8)) * scale, np.full((1, 8), scale), np.full((1, 8), -scale)):
        for row in code:
            table = decoder.decode(LatentRecord("x", row, np.ones(8)), masked="zero")
            assert np.isfinite(table).all() and (table >= 0).all()


def test_encode_many_names_each_source_by_its_file_hash_across_batches(
    tiny_model_folder: Path, analytic_tables: dict[str, MerlBRDF], tmp_path: Path
) -> None:
    """The sources' SHA-256 is taken on a thread of its own, batch by batch: each record still gets its own source's
    (the file's bytes; a clamped table keeps its source's; a converted measurement names the measurement)."""
    import dataclasses
    import hashlib
    import warnings

    from brdfcodec.codec import ClampWarning

    gold, chrome, plastic = (analytic_tables[n] for n in ("gold", "chrome", "red-plastic"))
    bright = MerlBRDF(np.where(gold.mask, gold.values * 1e12, gold.values), name="bright")  # clamped when encoded
    measured = dataclasses.replace(chrome, source_sha256="ab" * 32)
    tables = [gold, bright, measured, plastic, chrome]
    expected = []
    for i, table in enumerate(tables):
        path = tmp_path / f"m{i}.binary"
        write_merl(path, table)
        expected.append(table.source_sha256 or hashlib.sha256(path.read_bytes()).hexdigest())
    fresh = [dataclasses.replace(t) for t in tables]  # no hash cached yet
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ClampWarning)
        records = BrdfEncoder(tiny_model_folder, effort=0).encode_many(fresh, batch_size=2)
    assert [r.meta["source_sha256"] for r in records] == expected
