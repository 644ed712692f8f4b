"""Entropy-coded μ (format 2.5, ``spec/bvae-format.md`` §4.9): μ's integers ride ahead of the coefficients in a coded
basis layer's stream."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from brdfcodec.format.bvae import DecoderReference, encode_bvae, parse_bvae, record_size
from brdfcodec.format.layered_record import LayeredRecord
from brdfcodec.layers.basis import quantise_coefficients
from brdfcodec.layers.basis_layer import BasisLayer, coded_coefficients
from brdfcodec.layers.coded_basis import (
    MAX_MAGNITUDE,
    PRIOR_CODE_LIMIT,
    STOP_PROBABILITY,
    ZERO_PROBABILITY,
    choose_coding,
    coded_mu_codes,
    decode_integers,
    encode_integers,
    fit_prior_codes,
    ideal_code_bits,
    mu_stream_lead,
    prior_codes,
)
from brdfcodec.layers.packed import packed_step

SHA = "cd" * 32
DECODER = DecoderReference("ab" * 32, "test")


def _coefficients(seed: int = 1, k: int = 60) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.laplace(0, 1, k) * np.arange(9, 9 + k) ** -0.8


def _mu(seed: int = 2) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=8).astype(np.float32)


def _coded_mu_record(name: str = "gold", g: int = 4, max_bytes: int = 24) -> LayeredRecord:
    mu = _mu()
    q = np.rint(mu.astype(np.float64) * 2 ** g).astype(np.int64)
    layer = coded_coefficients(SHA, _coefficients(), max_bytes, (128, 40), first=8, coded_mu=(g, q))
    assert layer is not None
    return LayeredRecord(name, mu, np.ones(8), basis=layer, coded_mu=g, store_sigma=False)


def test_mu_is_on_the_grid_and_the_record_round_trips_as_2_5() -> None:
    record = _coded_mu_record()
    np.testing.assert_array_equal(record.mu, np.rint(_mu().astype(np.float64) * 16) / 16)
    assert record.mu_storage == "coded" and record.payload_values().size == 0
    data = encode_bvae([record], DECODER, latent_dtype="float16")
    assert data[8:12] == bytes([2, 0, 5, 0])
    parsed = parse_bvae(data)
    back = parsed.record("gold")
    assert isinstance(back, LayeredRecord) and back.coded_mu == 4 and back.basis is not None
    np.testing.assert_array_equal(back.mu, record.mu)
    assert back.basis.q.tolist() == record.basis.q.tolist()
    (entry,) = parsed.header.entries
    assert entry.layers["mu"] == "coded" and entry.layers["basis"]["mu_step"] == 4
    assert entry.length + entry.descriptor_bytes == record_size(record)
    assert encode_bvae([back], DECODER, latent_dtype="float16") == data  # read and written again: the same bytes


def test_the_stream_holds_mu_first_then_the_coefficients() -> None:
    """Decoded independently of the layer class: D integers under 16·g, then k under the form's prior codes."""
    record = _coded_mu_record(g=3)
    layer = record.basis
    assert layer is not None and layer.prior is not None
    data = layer.data
    codes = np.concatenate([np.full(8, 48), prior_codes(128, 40, data[0], 8, layer.count)])
    q = decode_integers(data[1:], codes)
    np.testing.assert_array_equal(q[:8], np.rint(record.mu.astype(np.float64) * 8))
    np.testing.assert_array_equal(q[8:], layer.q)
    assert encode_integers(q, codes) == data[1:]


def test_sharing_the_stream_costs_fewer_bytes_than_mu_on_the_fixed_grid() -> None:
    """The μ of a unit-variance code takes fewer bytes at 2^−4 in the layer's stream than 8 on the fixed grid."""
    sizes = []
    for seed in range(20):
        q = np.rint(_mu(seed).astype(np.float64) * 16).astype(np.int64)
        c = _coefficients(seed)
        alone = choose_coding(c, 8, 40, 128, 40)
        step = alone.step_code if alone is not None else 100
        k = len(alone.q) if alone is not None else 0
        with_mu = encode_integers(np.concatenate([q, alone.q if alone else []]),
                                  np.concatenate([coded_mu_codes(4, 8), prior_codes(128, 40, step, 8, k)]))
        sizes.append(len(with_mu) - len(alone.data if alone else b""))
    assert np.mean(sizes) < 7.5


def test_choose_coding_counts_the_lead_in_its_bytes() -> None:
    c = _coefficients()
    q = np.rint(_mu().astype(np.float64) * 16).astype(np.int64)
    lead = (q, coded_mu_codes(4, 8))
    alone = choose_coding(c, 8, 20, 128, 40)
    shared = choose_coding(c, 8, 20, 128, 40, lead=lead)
    assert alone is not None and shared is not None
    assert 1 + len(shared.data) <= 20 and len(shared.q) < len(alone.q)
    assert shared.data == encode_integers(np.concatenate([q, shared.q]),
                                          np.concatenate([lead[1], prior_codes(128, 40, shared.step_code, 8,
                                                                               len(shared.q))]))
    assert choose_coding(c, 8, 3, 128, 40, lead=lead) is None  # not even the lead fits


def test_an_edit_moves_mu_on_the_grid_and_the_layer_follows() -> None:
    record = _coded_mu_record()
    edited = dataclasses.replace(record, mu=record.mu + np.float32(0.3))
    assert edited.basis is not None and edited.basis.coded_mu is not None
    np.testing.assert_array_equal(edited.basis.coded_mu[1], np.rint((record.mu + np.float32(0.3)) * 16))
    back = parse_bvae(encode_bvae([edited], DECODER)).record("gold")
    np.testing.assert_array_equal(back.mu, edited.mu)
    # the same layer without the coded μ: μ back in the latent dtype, the stream the coefficients' alone
    plain = dataclasses.replace(record, coded_mu=0)
    assert plain.basis is not None and plain.basis.coded_mu is None and plain.payload_values().size == 8
    assert plain.basis.nbytes < record.basis.nbytes


@pytest.mark.parametrize("bad", [np.full(8, 1e9), np.array([np.nan] + [0.0] * 7)])
def test_a_mu_past_the_coder_range_is_refused(bad: np.ndarray) -> None:
    record = _coded_mu_record()
    with pytest.raises(ValueError, match="range|finite"):
        dataclasses.replace(record, mu=bad.astype(np.float32))


def test_extreme_but_representable_mu_round_trips_finite() -> None:
    record = _coded_mu_record()
    big = np.full(8, (MAX_MAGNITUDE - 1) / 16, dtype=np.float32)
    edited = dataclasses.replace(record, mu=big)
    back = parse_bvae(encode_bvae([edited], DECODER)).record("gold")
    assert np.isfinite(back.mu).all() and back.mu.tolist() == edited.mu.tolist()


def test_a_coded_mu_needs_a_coded_layer_and_a_grid_of_1_to_5() -> None:
    record = _coded_mu_record()
    packed = BasisLayer(SHA, packed_step(100), np.array([3, -2, 1]), 8, 0, top=9)
    with pytest.raises(ValueError, match="entropy-coded"):
        LayeredRecord("a", _mu(), np.ones(8), basis=packed, coded_mu=4, store_sigma=False)
    with pytest.raises(ValueError, match="entropy-coded"):
        LayeredRecord("a", _mu(), np.ones(8), basis=None, detail=None, coded_mu=4, store_sigma=False)
    for g in (0, 6, True):
        if g == 0:
            continue  # 0 means: not coded
        with pytest.raises(ValueError, match="grid exponent"):
            dataclasses.replace(record, coded_mu=g)
    with pytest.raises(ValueError, match="compact"):
        dataclasses.replace(record, compact_mu=True)
    with pytest.raises(ValueError, match="grid exponent"):
        coded_mu_codes(6, 8)


def test_info_says_mu_is_coded(tmp_path, capsys) -> None:
    import json

    from brdfcodec.cli.main import main

    path = tmp_path / "coded-mu.bvae"
    path.write_bytes(encode_bvae([_coded_mu_record()], DECODER))
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "format 2.5" in out and "μ coded in the basis layer, grid 2^-4" in out
    assert main(["info", "--json", str(path)]) == 0
    (item,) = json.loads(capsys.readouterr().out)["materials"]
    assert item["mu"] == "coded" and item["mu_step"] == 4


@pytest.mark.slow  # encodes with the shipped model
def test_rate_control_offers_coded_mu_and_keeps_the_least_error(red_plastic_file, tmp_path) -> None:
    """``bvae compress --bytes 32``: the chosen record fits, keeps a latent, decodes to what it measured; its rate
    points include records with a coded μ, and the one kept errs least among those that fit; ``--basis-coding
    packed`` writes none."""
    from brdfcodec.cli.main import main
    from brdfcodec.codec import BrdfDecoder
    from brdfcodec.format.bvae import read_bvae

    out = tmp_path / "auto.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(out), "--bytes", "32", "--no-measure"]) == 0
    (record,) = read_bvae(out).records
    (entry,) = parse_bvae(out.read_bytes()).header.entries
    assert record.has_latent and entry.length + entry.descriptor_bytes <= 32
    assert np.isfinite(BrdfDecoder().decode(record)).all()
    packed = tmp_path / "packed.bvae"
    assert main(["compress", str(red_plastic_file), "-o", str(packed), "--bytes", "32", "--basis-coding", "packed",
                 "--no-measure"]) == 0
    (record,) = read_bvae(packed).records
    assert record.coded_mu == 0 and record.basis is not None and record.basis.prior is None


def test_the_stream_lead_of_a_coded_mu_is_its_integers_under_16g() -> None:
    q, codes = mu_stream_lead((3, np.array([1, -2, 0], dtype=np.int16)))
    assert q.dtype == np.int64 and q.tolist() == [1, -2, 0] and codes.tolist() == [48, 48, 48]
    record = _coded_mu_record(g=2)
    assert [a.tolist() for a in record.basis.stream_codes()] == [a.tolist() for a in mu_stream_lead(
        record.basis.coded_mu)]
    with pytest.raises(ValueError, match="1 to 5"):
        mu_stream_lead((6, [0]))


@pytest.mark.parametrize("bad", [-1, 6, 2.5, True, "3", np.float64(3), (3, 3), (3, 0), [2, 6], (None,)])
def test_the_coded_mu_step_option_is_0_to_5_or_distinct_grids(bad: object) -> None:
    from brdfcodec.codec.encoding import EncodeOptions

    with pytest.raises(ValueError, match="coded_mu_step"):
        EncodeOptions(bytes_budget=32, coded_mu_step=bad)  # type: ignore[arg-type]
    step = EncodeOptions(bytes_budget=32, coded_mu_step=np.int64(4)).coded_mu_step
    assert step == (4,) and type(step[0]) is int
    assert EncodeOptions(bytes_budget=32, coded_mu_step=[2, np.int64(3)]).coded_mu_step == (2, 3)
    assert EncodeOptions(bytes_budget=32, coded_mu_step=0).coded_mu_step == ()


def test_the_coded_mu_grids_are_offered_only_where_coded_layers_are() -> None:
    from brdfcodec.codec.encoding import (
        CODED_MU_COARSER_BUDGET,
        CODED_MU_COARSER_REACH,
        CODED_MU_STEP_LOG2,
        CODED_MU_STEPS_LOG2,
        EncodeOptions,
    )

    assert EncodeOptions(bytes_budget=32).coded_mu_grids == CODED_MU_STEPS_LOG2 == (CODED_MU_STEP_LOG2, 2)
    assert CODED_MU_COARSER_BUDGET == 32  # the default's second grid: up to 32 B, where it was measured ...
    assert EncodeOptions(bytes_budget=32).coded_mu_caps == {}
    # ... and its records of at most 32 B up to 40 B, so that a byte more does not lose them
    assert EncodeOptions(bytes_budget=33).coded_mu_grids == CODED_MU_STEPS_LOG2 == EncodeOptions(
        bytes_budget=CODED_MU_COARSER_REACH).coded_mu_grids
    assert EncodeOptions(bytes_budget=CODED_MU_COARSER_REACH).coded_mu_caps == {2: CODED_MU_COARSER_BUDGET}
    assert EncodeOptions(bytes_budget=CODED_MU_COARSER_REACH + 1).coded_mu_grids == (CODED_MU_STEP_LOG2,)
    assert EncodeOptions(bytes_budget=64, coded_mu_step=(3, 2)).coded_mu_caps == {}  # asked for: not capped
    assert EncodeOptions(max_relae=0.05).coded_mu_grids == (CODED_MU_STEP_LOG2,)
    assert EncodeOptions(bytes_budget=64, coded_mu_step=(3, 2)).coded_mu_grids == (3, 2)  # asked: offered
    assert EncodeOptions(max_relae=0.05, coded_mu_step=4).coded_mu_grids == (4,)
    assert EncodeOptions(bytes_budget=32, coded_mu_step=0).coded_mu_grids == ()
    assert EncodeOptions(bytes_budget=32, basis_coding="packed").coded_mu_grids == ()
    assert EncodeOptions().coded_mu_grids == ()  # no target: no rate control


@pytest.mark.parametrize("better", [3, 2])
def test_a_budget_keeps_the_coded_mu_grid_of_lower_error(better: int) -> None:
    """Rate control's coded-μ candidates on each grid asked for (the default: 2^−3 and 2^−2) are pools of their
    own, their fits told the grid; the record of least kept-slice error is written, on its grid."""
    from brdfcodec.codec.rate import encode_layers
    from brdfcodec.conventions import NETWORK_INPUT_SHAPE
    from brdfcodec.format.bvae import LatentRecord

    target = np.full(NETWORK_INPUT_SHAPE, 0.5, dtype=np.float32)
    masks = np.ones(NETWORK_INPUT_SHAPE, dtype=np.float32)
    base = LatentRecord("m", _mu(), np.ones(8))
    grids: list[int] = []

    def fit(k: int, mu_storage: str | None, under_detail: bool, variant: str | None = None, *,  # noqa: ARG001
            grid: int = 0) -> tuple:
        if mu_storage != "coded":  # the other candidates: worse than either coded one
            return base, quantise_coefficients(SHA, np.ones(k)), target * 0.5
        grids.append(grid)
        q = np.rint(base.mu.astype(np.float64) * 2 ** grid).astype(np.int64)
        layer = coded_coefficients(SHA, _coefficients(k=k), k - 1, (128, 40), first=8, coded_mu=(grid, q))
        code = LatentRecord("m", (q / 2.0 ** grid).astype(np.float32), base.sigma)
        return code, layer, target * (0.99 if grid == better else 0.9)

    result = encode_layers(base, target * 0.5, target, masks, bytes_budget=24, basis_fit=fit, basis_count=75,
                           basis_variants=("8",), coded_mu_steps=(3, 2))
    assert set(grids) == {3, 2}
    assert {p.label.split(" k=")[0] for p in result.points} >= {"coded-mu g=3", "coded-mu g=2"}
    assert result.record.coded_mu == better and result.record.basis.coded_mu[0] == better
    assert record_size(result.record) == result.payload_bytes <= 24


def test_a_capped_grid_offers_above_its_cap_the_records_it_offers_at_its_cap() -> None:
    """A grid whose records are capped (the default's coarser grid between 33 and 40 B) offers under a larger budget
    the same candidates as under the cap, so that the budget a byte above never loses the record it gave."""
    from brdfcodec.codec.rate import encode_layers
    from brdfcodec.conventions import NETWORK_INPUT_SHAPE
    from brdfcodec.format.bvae import LatentRecord

    target = np.full(NETWORK_INPUT_SHAPE, 0.5, dtype=np.float32)
    masks = np.ones(NETWORK_INPUT_SHAPE, dtype=np.float32)
    base = LatentRecord("m", _mu(), np.ones(8))

    def fit(k: int, mu_storage: str | None, under_detail: bool, variant: str | None = None, *,  # noqa: ARG001
            grid: int = 0) -> tuple:
        if mu_storage != "coded":
            return base, quantise_coefficients(SHA, np.ones(k)), target * 0.5
        q = np.rint(base.mu.astype(np.float64) * 2 ** grid).astype(np.int64)
        layer = coded_coefficients(SHA, _coefficients(k=k), k - 1, (128, 40), first=8, coded_mu=(grid, q))
        code = LatentRecord("m", (q / 2.0 ** grid).astype(np.float32), base.sigma)
        return code, layer, target * (0.99 if grid == 2 else 0.9 + 0.001 * k)  # only grid 2 is close

    def encode(budget: int, caps: dict[int, int] | None) -> object:
        return encode_layers(base, target * 0.5, target, masks, bytes_budget=budget, basis_fit=fit, basis_count=75,
                             basis_variants=("8",), coded_mu_steps=(3, 2), coded_mu_caps=caps).record

    at_cap = encode(32, None)
    assert at_cap.coded_mu == 2
    capped = encode(36, {2: 32})
    assert capped.coded_mu == 2 and record_size(capped) == record_size(at_cap) <= 32
    assert capped.basis.q.tolist() == at_cap.basis.q.tolist()
    assert record_size(encode(36, None)) > 32  # uncapped, the grid's records grow with the budget


def test_an_error_target_keeps_the_smallest_coded_mu_record_over_the_grids() -> None:
    """Under an error target each grid's coded-μ records are bisected below the ladder's choice and the smallest
    that meets the target is written: the coarser grid's where it meets the target with fewer coefficients (here
    10 on 2^−2 against 20 on 2^−3), whichever grid is listed first."""
    from brdfcodec.codec import rate
    from brdfcodec.conventions import N_CHANNELS, N_PHI_D, N_THETA_D, N_THETA_H, NETWORK_INPUT_SHAPE
    from brdfcodec.format.bvae import LatentRecord

    target = np.full(NETWORK_INPUT_SHAPE, 0.5, dtype=np.float32)
    masks = np.ones(NETWORK_INPUT_SHAPE, dtype=np.float32)
    base = LatentRecord("m", _mu(), np.ones(8))
    values = np.ones((N_CHANNELS, N_THETA_H, N_THETA_D, N_PHI_D))
    mask = np.ones(values.shape, dtype=bool)

    def fit(k: int, mu_storage: str | None, under_detail: bool, variant: str | None = None, *,  # noqa: ARG001
            grid: int = 0) -> tuple:
        if mu_storage != "coded":  # every other candidate decodes to the target only with all K coefficients
            return base, quantise_coefficients(SHA, np.ones(k)), target * (1.0 if k >= 75 else 0.5)
        q = np.rint(base.mu.astype(np.float64) * 2 ** grid).astype(np.int64)
        layer = coded_coefficients(SHA, _coefficients(k=k), k - 1, (128, 40), first=8, coded_mu=(grid, q))
        code = LatentRecord("m", (q / 2.0 ** grid).astype(np.float32), base.sigma)
        return code, layer, target * (1.0 if k >= (10 if grid == 2 else 20) else 0.5)

    def relae(table: np.ndarray) -> float:  # the error of a decode: 0 where it is the target, else 1
        return 0.0 if np.allclose(table, reference) else 1.0

    reference = rate.table_from_network_output(target)
    original = rate.RelaeAgainst

    class Exact:
        def __init__(self, *args: object) -> None:
            pass

        def __call__(self, table: np.ndarray) -> object:
            return type("R", (), {"overall": relae(table)})()

    try:
        rate.RelaeAgainst = Exact  # type: ignore[misc, assignment]
        results = [rate.encode_layers(base, target * 0.5, target, masks, values=values, mask=mask, max_relae=0.5,
                                      basis_fit=fit, basis_count=75, coded_mu_steps=grids)
                   for grids in ((3, 2), (2, 3), (3,))]
    finally:
        rate.RelaeAgainst = original  # type: ignore[misc]
    assert [result.record.coded_mu for result in results] == [2, 2, 3]
    assert results[0].payload_bytes == results[1].payload_bytes < results[2].payload_bytes
    assert all(record_size(result.record) == result.payload_bytes for result in results)


@pytest.mark.slow  # encodes with the shipped model
@pytest.mark.parametrize("g", [2, 4])
def test_the_grid_asked_for_is_the_grid_written(red_plastic_file, g: int) -> None:
    """``BrdfEncoder(coded_mu_step=g)`` at 16 B (where the coded-μ record is the only layered one with a latent):
    the record's μ is on the grid 2^−g and its stream leads with those integers."""
    from brdfcodec.codec import BrdfEncoder
    from brdfcodec.io.merl import read_merl

    record = BrdfEncoder(bytes=16, latent_dtype="float16", coded_mu_step=g).encode(read_merl(red_plastic_file),
                                                                                name="red")
    assert record.coded_mu == g and record.basis is not None and record.basis.coded_mu is not None
    assert record.basis.coded_mu[0] == g
    np.testing.assert_array_equal(record.mu, record.basis.coded_mu[1] / 2.0 ** g)


@pytest.mark.slow  # encodes with the shipped model
def test_the_rate_points_include_coded_mu_records(red_plastic_file, monkeypatch) -> None:
    import brdfcodec as bc
    import brdfcodec.codec.rate as rate
    from brdfcodec.codec.rate import lowest_distortion

    seen: dict[str, list] = {}

    def spy(points, budget):
        seen["points"] = list(points)
        return lowest_distortion(points, budget)

    monkeypatch.setattr(rate, "lowest_distortion", spy)
    data = bc.encode([str(red_plastic_file)], bytes=32, measure_error=False)
    monkeypatch.undo()
    labels = [p.label for p in seen["points"]]
    assert any(label.startswith("coded-mu g=3") for label in labels), labels  # the default grids, each a pool
    assert any(label.startswith("coded-mu g=2") for label in labels), labels
    chosen = seen["points"][lowest_distortion(seen["points"], 32)]
    assert all(p.distortion >= chosen.distortion for p in seen["points"] if p.rate <= 32)
    record = bc.decode(data).record(bc.decode(data).names[0])
    assert record.coded_mu == getattr(chosen.pool, "coded_mu_step", 0)  # the chosen pool's grid, or none
    assert (record.coded_mu != 0) == chosen.label.startswith("coded-mu")
    for point in seen["points"]:  # every candidate is the record of its rate, on its pool's grid
        made = point.pool.record(*point.option)
        if getattr(made, "coded_mu", 0):
            assert made.coded_mu == made.basis.coded_mu[0] == point.pool.coded_mu_step, point.label
        assert record_size(made) == point.rate, point.label


def test_an_edit_off_the_grid_stores_mu_in_the_latent_dtype_and_keeps_the_coefficients() -> None:
    from brdfcodec.edit.latent_edits import traverse

    record = _coded_mu_record()
    (on_grid,) = traverse(record, 0, [0.25])  # σ-less records: offsets in units of the prior's width, 1
    (off_grid,) = traverse(record, 0, [0.01])
    assert on_grid.coded_mu == 4 and off_grid.coded_mu == 0
    assert off_grid.mu[0] == np.float32(record.mu[0] + np.float32(0.01))
    assert off_grid.basis.q.tolist() == record.basis.q.tolist() and off_grid.basis.coded_mu is None
    for edited in (on_grid, off_grid):
        back = parse_bvae(encode_bvae([edited], DECODER)).record(edited.name)
        np.testing.assert_array_equal(back.mu, edited.mu)


@pytest.mark.slow  # two encodes with the shipped model
def test_an_error_target_takes_a_smaller_coded_mu_record_that_meets_it(red_plastic_file) -> None:
    """``--max-relae``: where a record whose μ rides in its coded layer meets the target in fewer bytes than every
    other candidate, it is the one written, and its decode meets the target; with the candidates off, the larger
    record comes back."""
    from brdfcodec.codec import BrdfDecoder, BrdfEncoder
    from brdfcodec.io.merl import read_merl
    from brdfcodec.representation.metrics import relae_mapped

    source = read_merl(red_plastic_file)
    records = {g: BrdfEncoder(max_relae=0.05, latent_dtype="float16", coded_mu_step=g).encode(source, name="red")
               for g in (0, 3)}
    assert records[3].coded_mu == 3 and records[0].coded_mu == 0
    assert records[3].meta["rate"]["record_bytes"] < records[0].meta["rate"]["record_bytes"]
    table = BrdfDecoder().decode(records[3])
    assert relae_mapped(source.values, table, source.mask).overall <= 0.05


def test_the_ideal_code_length_prices_each_bit_as_the_tables_say_and_is_close_to_the_coder_s_bytes() -> None:
    """``ideal_code_bits`` is −log₂ of the tables' probabilities, bit by bit; on short streams the coder's bytes
    hold those bits and a few more (its termination)."""
    zero, stop = ZERO_PROBABILITY[32 + PRIOR_CODE_LIMIT] / 256, STOP_PROBABILITY[32 + PRIOR_CODE_LIMIT] / 256
    assert ideal_code_bits([0], [32]) == pytest.approx(-np.log2(zero))
    # −2 under code 32: "not 0", the sign (1/2), "m > 1" (not a stop), then the stop at 2
    assert ideal_code_bits([-2], [32]) == pytest.approx(-np.log2((1 - zero) * 0.5 * (1 - stop) * stop))
    rng = np.random.default_rng(7)
    differences = []
    for _ in range(200):
        q = np.round(rng.laplace(0.0, 3.0, size=12)).astype(np.int64)
        codes = rng.integers(-20, 60, size=12)
        differences.append(8 * len(encode_integers(q, codes)) - ideal_code_bits(q, codes))
    assert 0.0 < float(np.mean(differences)) < 5.0
    with pytest.raises(ValueError, match="prior codes"):
        ideal_code_bits([1, 2], [32])
    with pytest.raises(ValueError, match="prior code lies outside"):
        ideal_code_bits([1], [PRIOR_CODE_LIMIT + 1])


def test_fitted_prior_codes_follow_each_dimension_s_spread() -> None:
    """A prior code per column, of least ideal length: a column that is always 0 gets the narrowest prior, a
    Laplace column of scale b steps the code 16·log₂(√2·b) (the format's spread σ = √2·b), and each fit codes
    its column shorter than the unit prior of the grid 2^−2 (code 32) does where the column is far from unit
    spread."""
    rng = np.random.default_rng(3)
    wide = np.round(rng.laplace(0.0, 8.0, size=400)).astype(np.int64)
    narrow = np.round(rng.laplace(0.0, 0.5, size=400)).astype(np.int64)
    q = np.stack([wide, narrow, np.zeros(400, dtype=np.int64)], axis=1)
    codes = fit_prior_codes(q)
    assert abs(int(codes[0]) - 16 * np.log2(np.sqrt(2.0) * 8.0)) <= 6
    assert codes[0] > codes[1] > codes[2] == -PRIOR_CODE_LIMIT
    for column, code in zip(q.T, codes, strict=True):
        assert ideal_code_bits(column, np.full(400, code)) < ideal_code_bits(column, np.full(400, 32)) - 40
    for bad in (np.zeros((0, 3), dtype=np.int64), np.zeros(3, dtype=np.int64)):
        with pytest.raises(ValueError, match="fit_prior_codes"):
            fit_prior_codes(bad)
