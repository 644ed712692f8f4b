"""Records that store μ without σ (format 2.2; issue 41 part 3: the shipped model's σ carries no information)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import brdfcodec as bc
from brdfcodec.cli.main import main
from brdfcodec.codec import BrdfDecoder, BrdfEncoder
from brdfcodec.errors import BvaeFormatError
from brdfcodec.format.bvae import DecoderReference, LatentRecord, encode_bvae, parse_bvae, read_bvae
from brdfcodec.format.layered_record import LayeredRecord

REFERENCE = DecoderReference("ab" * 32, "test")


def _record(name: str = "a") -> LatentRecord:
    return LatentRecord(name, np.linspace(-1, 1, 8, dtype=np.float32), np.full(8, 0.003, dtype=np.float32))


def test_a_record_without_sigma_stores_half_the_payload_and_reads_sigma_as_one() -> None:
    plain, bare = encode_bvae([_record()], REFERENCE), encode_bvae([LayeredRecord.code_only(_record())], REFERENCE)
    assert len(plain) - len(bare) == 8 * 4 - 3  # 32 B of σ gone; the layered form costs 3 bytes more
    parsed = parse_bvae(bare)
    record = parsed.records[0]
    assert (parsed.header.major, parsed.header.minor) == (2, 2)
    assert isinstance(record, LayeredRecord) and not record.store_sigma and not record.has_layers
    np.testing.assert_array_equal(record.mu, _record().mu)
    np.testing.assert_array_equal(record.sigma, np.ones(8, dtype=np.float32))
    assert parse_bvae(plain).header.minor == 1  # a file without such a record is written as 2.1, as before


def test_sigma_is_left_out_only_with_a_latent_and_not_beside_compact_sigma() -> None:
    with pytest.raises(ValueError, match="not stored or stored compactly"):
        LayeredRecord("a", np.zeros(8), np.ones(8), store_sigma=False, shared_sigma=True)
    with pytest.raises(ValueError, match="needs a basis layer, a detail layer or both"):
        LayeredRecord("a", np.zeros(8), np.ones(8))  # the base alone only without a stored σ


def test_a_truncated_record_without_sigma_is_refused_with_the_file_name() -> None:
    data = encode_bvae([LayeredRecord.code_only(_record())], REFERENCE)
    with pytest.raises(BvaeFormatError, match="cut.bvae"):
        parse_bvae(data[:-4], "cut.bvae")


@pytest.fixture(scope="module")
def gold_binary(tmp_path_factory: pytest.TempPathFactory, analytic_tables) -> Path:
    path = tmp_path_factory.mktemp("no-sigma") / "gold.binary"
    bc.write_merl(path, analytic_tables["gold"])
    return path


def test_compress_leaves_sigma_out_by_default_and_decodes_the_same(gold_binary: Path, tmp_path: Path) -> None:
    lean, full = tmp_path / "lean.bvae", tmp_path / "full.bvae"
    assert main(["compress", str(gold_binary), "-o", str(lean), "--no-measure"]) == 0
    assert main(["compress", str(gold_binary), "-o", str(full), "--no-measure", "--sigma"]) == 0
    assert full.stat().st_size - lean.stat().st_size == 8 * 4 - 3
    bare, kept = read_bvae(lean).records[0], read_bvae(full).records[0]
    assert not bare.store_sigma and kept.kind == "latent" and float(kept.sigma.max()) < 1
    decoder = BrdfDecoder()
    np.testing.assert_array_equal(decoder.decode(bare), decoder.decode(kept))
    edited = tmp_path / "edited.bvae"
    assert main(["edit", "traverse", str(lean), "--dim", "1", "--values", "1", "-o", str(edited)]) == 0  # editable
    assert not read_bvae(edited).records[0].store_sigma


def test_under_a_size_budget_sigma_bytes_go_to_the_basis_layer(analytic_tables) -> None:
    brdf = analytic_tables["gold"]
    assert BrdfEncoder(effort=0, store_sigma=True).encode(brdf).kind == "latent"
    assert not BrdfEncoder(effort=0).encode(brdf).store_sigma
    # int8 coefficients, one byte each (packed layers: test_packed_basis.py)
    lean = BrdfEncoder(effort=0, bytes=64, latent="always", project_base="never", basis_coding="int8").encode(brdf)
    kept = BrdfEncoder(effort=0, bytes=64, latent="always", project_base="never", store_sigma=True,
                       basis_coding="int8").encode(brdf)
    assert lean.kind == kept.kind == "layered" and lean.compact_mu and kept.compact_mu
    assert not lean.store_sigma and kept.shared_sigma  # one byte of σ ...
    assert lean.basis.count == kept.basis.count + 1  # ... is one more coefficient
