"""The smallest record with a latent: the base alone, μ stored compact, no σ and no layer (format 2.2).

Rate control offers it under every size budget it fits (``brdfcodec.codec.rate._CompactAlone``), so that
``bvae compress --bytes N`` with its default ``--latent always`` writes an editable record from 10 bytes (D = 8, a
one-byte name) instead of refusing budgets below the compact base with one basis coefficient (14 bytes).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from brdfcodec.codec.rate import encode_layers, smallest_bytes_budget
from brdfcodec.conventions import NETWORK_INPUT_SHAPE
from brdfcodec.errors import RateTargetError
from brdfcodec.format.bvae import LatentRecord, record_overhead, record_size
from brdfcodec.format.layered_record import MU_INT8_FIXED, LayeredRecord, compact_mu_values
from brdfcodec.layers.basis import quantise_coefficients

_BASIS_COUNT = 75


def _case(mu: np.ndarray, alone_error: float = 0.05, layered_error: float = 0.01):
    """A target, a base and fits whose decodes sit a known offset from the target: the compact base alone at
    ``alone_error``, every layered candidate at ``layered_error`` (and the base in the latent dtype at 0.1)."""
    target = np.full(NETWORK_INPUT_SHAPE, 0.5, dtype=np.float32)
    masks = np.ones(NETWORK_INPUT_SHAPE, dtype=np.float32)
    base = LatentRecord("m", mu.astype(np.float32), np.ones(len(mu), np.float32), {})

    def basis_fit(k: int, mu_storage, under_detail: bool):
        return base, quantise_coefficients("0" * 64, np.linspace(0.1, 1.0, k)), target + layered_error

    def alone_fit(storage: str):
        return compact_mu_values(base.mu, storage == MU_INT8_FIXED), target + alone_error

    return base, target, masks, basis_fit, alone_fit


def _encode(case, budget: int, *, store_sigma: bool = False, with_alone: bool = True):
    base, target, masks, basis_fit, alone_fit = case
    return encode_layers(base, target + 0.1, target, masks, bytes_budget=budget, latent_itemsize=2,
                         basis_fit=basis_fit, basis_count=_BASIS_COUNT, store_sigma=store_sigma,
                         compact_alone_fit=alone_fit if with_alone else None)


def test_a_budget_below_one_coefficient_holds_the_base_alone_on_the_grid() -> None:
    case = _case(np.array([0.5, -1.0, 2.0, 0.1, 0.0, 0.0, 3.0, -3.9]))
    result = _encode(case, 10)
    record = result.record
    assert isinstance(record, LayeredRecord)
    assert record.basis is None and record.detail is None and record.compact_mu and record.fixed_mu_grid
    assert not record.store_sigma
    assert result.payload_bytes == record_size(record) == 8 + record_overhead("m") == 10
    np.testing.assert_array_equal(record.mu, compact_mu_values(case[0].mu, True))


def test_a_code_past_the_grid_takes_its_step_where_the_budget_has_room_else_the_grid_end() -> None:
    mu = np.array([5.5, -1.0, 2.0, 0.1, 0.0, 0.0, 3.0, -3.9])
    assert _encode(_case(mu), 10).record.fixed_mu_grid  # 10 B: the grid, 5.5 stored at its end
    assert _encode(_case(mu), 10).record.mu[0] == pytest.approx(127 / 32)
    at_twelve = _encode(_case(mu), 12).record  # 12 B: the float16 step and 8 bytes, μ kept
    assert at_twelve.compact_mu and not at_twelve.fixed_mu_grid
    assert at_twelve.mu[0] == pytest.approx(5.5, abs=0.03)


def test_the_base_alone_is_no_candidate_with_sigma_or_without_its_fit() -> None:
    mu = np.zeros(8)
    with pytest.raises(RateTargetError, match="10 bytes is below"):
        _encode(_case(mu), 10, store_sigma=True)  # spec §3.2: a form with σ must hold a layer
    with pytest.raises(RateTargetError, match="10 bytes is below"):
        _encode(_case(mu), 10, with_alone=False)


def test_the_base_alone_stays_a_candidate_where_layered_records_fit() -> None:
    """Rate control keeps it where it errs less than every layered record that fits (a byte more never loses what
    a smaller budget gave), and the layered record where that errs less."""
    mu = np.zeros(8)
    worse_layers = _encode(_case(mu, alone_error=0.01, layered_error=0.05), 24).record
    assert isinstance(worse_layers, LayeredRecord) and worse_layers.basis is None and worse_layers.compact_mu
    better_layers = _encode(_case(mu, alone_error=0.05, layered_error=0.01), 24).record
    assert isinstance(better_layers, LayeredRecord) and better_layers.basis is not None


def test_the_floor_checked_up_front_is_the_base_alone_without_sigma() -> None:
    assert smallest_bytes_budget(8, 4, basis=True, store_sigma=False) == 8 + record_overhead("a")
    assert smallest_bytes_budget(8, 2, basis=False, store_sigma=False) == 8 + record_overhead("a")
    assert smallest_bytes_budget(8, 4, basis=True, store_sigma=True) == 8 + 1 + 2 + 1 + record_overhead(
        "a", basis_count=1)


def test_the_shipped_model_writes_an_editable_ten_byte_record(tmp_path: Path, red_plastic_file: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """Through the CLI with its defaults (a latent in every record, no σ): at most 10 bytes per record beside the
    name, a file that reads back and can be edited. The base alone, μ compact (10 bytes, decoding as the decoder's
    output for the stored code), is the record without the coded-μ candidates; with them (the default) a coded μ
    on the coarser grid with a few coefficients may fit the same bytes and err less."""
    from brdfcodec.cli import main
    from brdfcodec.codec import BrdfDecoder, BrdfEncoder
    from brdfcodec.format.bvae import read_bvae
    from brdfcodec.io.merl import read_merl
    from brdfcodec.representation import network_input_from_table

    output = tmp_path / "ten.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(output), "--bytes", "10"]) == 0
    assert main(["compress", str(red_plastic_file), "-o", str(tmp_path / "nine.bvae"), "--bytes", "9"]) == 2
    assert not (tmp_path / "nine.bvae").exists()
    capsys.readouterr()
    parsed = read_bvae(output)
    (written,) = parsed.records
    assert isinstance(written, LayeredRecord) and written.has_latent and written.detail is None
    assert record_size(written) <= 10
    source = read_merl(red_plastic_file)
    record = BrdfEncoder(bytes=10, coded_mu_step=0).encode(source, name="red-plastic")
    assert isinstance(record, LayeredRecord) and record.has_latent and record.basis is None and record.detail is None
    assert record_size(record) == 10  # the payload (8) and the descriptor beside the name
    decoder = BrdfDecoder()
    np.testing.assert_array_equal(decoder.mapped_record(record), decoder.decode_mapped(record.mu))
    # what the default wrote instead errs no more on what rate control ranks by (the clamped kept slices' L1)
    inputs, mask = network_input_from_table(source.values, source.mask)

    def kept_error(chosen: LayeredRecord) -> float:
        return float((np.abs(decoder.mapped_record(chosen) - inputs) * mask).sum())

    assert kept_error(written) <= kept_error(record)
    record = written
    edited = tmp_path / "edited.bvae"
    assert main(["edit", "traverse", str(output), "-o", str(edited), "--dim", "1", "--values", "1"]) == 0, \
        capsys.readouterr().err
    assert not np.array_equal(read_bvae(edited).records[0].mu, record.mu)
