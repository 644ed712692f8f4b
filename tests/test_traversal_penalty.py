"""The traversal plausibility penalty of training (brdfcodec.training.traversal) and its wiring into the trainer."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

from brdfcodec.datasets.hdf5 import build_dataset
from brdfcodec.datasets.sources import analytic_sources
from brdfcodec.edit.plausibility import inverted_cells, new_holes, pit_cells, white_sky_albedo
from brdfcodec.models.config import TINY_CONFIG
from brdfcodec.models.loss import beta_norm
from brdfcodec.training.config import TrainConfig
from brdfcodec.training.trainer import _global_batches, train
from brdfcodec.training.traversal import ENERGY_SCALE, TraversalPenalty, traversed_codes

GREEN, SLOT, THETA_D = 1, 10, 10  # a cell above the horizon (φd bin 90, θd bin 10)


def channel(colour: int, slot: int) -> int:
    return colour * 21 + slot


@pytest.fixture(scope="module")
def flat() -> torch.Tensor:
    return torch.full((1, 63, 90, 90), 0.5)


@pytest.fixture(scope="module")
def penalty(flat: torch.Tensor) -> TraversalPenalty:
    return TraversalPenalty(flat)


def test_albedo_limit_is_the_training_materials_largest_with_the_margin(flat: torch.Tensor) -> None:
    brighter = flat.clone()
    brighter[:, 0:21] = 0.8  # red brighter than green and blue
    expected = float(white_sky_albedo(brighter.numpy()).max())
    assert TraversalPenalty(torch.cat([flat, brighter]), energy_margin=0.1).albedo_limit == pytest.approx(
        1.1 * expected, rel=1e-4)
    with pytest.raises(ValueError, match="no energy"):
        TraversalPenalty(torch.zeros(1, 63, 90, 90))
    with pytest.raises(ValueError, match="margin"):
        TraversalPenalty(flat, margin=-0.1)


def test_inversion_counts_a_new_deficit_beyond_the_margin_once_per_cell(flat, penalty) -> None:
    edited = flat.clone()
    edited[0, channel(GREEN, SLOT), 0:2, THETA_D] = 0.2  # peak 0.3 below its flank
    terms = penalty(edited, flat)
    assert float(terms.inversion[0]) == pytest.approx(0.3 - penalty.margin, abs=1e-6)
    assert float(terms.holes[0]) == 0 and float(terms.energy[0]) == 0
    assert inverted_cells(edited[0].numpy())[GREEN, SLOT, THETA_D]  # the plausibility check flags the same cell
    # The material's own deficit is allowed: no penalty when the source has the same dip.
    assert float(penalty(edited, edited).inversion[0]) == 0


def test_a_peak_below_the_floor_under_a_lit_flank_is_a_hole(flat, penalty) -> None:
    edited = flat.clone()
    edited[0, channel(GREEN, SLOT), 0, THETA_D] = -0.25
    terms = penalty(edited, flat)
    assert float(terms.holes[0]) == pytest.approx(0.25, abs=1e-6)
    assert new_holes(flat[0].numpy(), edited[0].clamp(0, 5).numpy()).any()
    # The deficit is judged on the floored output: 0.5 − max(0, 0.5) at θh 0–1 is no inversion (bin 1 is lit).
    assert float(terms.inversion[0]) == 0
    # With the whole peak below the floor, the deficit is the flank over 0, not over the negative output.
    pit = flat.clone()
    pit[0, channel(GREEN, SLOT), 0:2, THETA_D] = -0.25
    terms = penalty(pit, flat)
    assert float(terms.inversion[0]) == pytest.approx(0.5 - penalty.margin, abs=1e-6)
    assert float(terms.holes[0]) == pytest.approx(0.5, abs=1e-6)
    # A region that goes black as a whole, flank included, is not a hole.
    dark = flat.clone()
    dark[0, channel(GREEN, SLOT), 0:7, THETA_D] = -0.25
    assert float(penalty(dark, flat).holes[0]) == 0
    # Nor where the material itself is black.
    black_source = flat.clone()
    black_source[0, channel(GREEN, SLOT), 0, THETA_D] = 0.0
    assert float(penalty(edited, black_source).holes[0]) == 0


def test_hole_margin_keeps_a_lit_peak_above_the_floor(flat: torch.Tensor, penalty) -> None:
    edited = flat.clone()
    edited[0, channel(GREEN, SLOT), 0, THETA_D] = 0.01  # just above the floor: no hole without a margin
    assert float(penalty(edited, flat).holes[0]) == 0
    kept = TraversalPenalty(flat, hole_margin=0.05)
    assert float(kept(edited, flat).holes[0]) == pytest.approx(0.04, abs=1e-6)
    # The material's own value, where lower than the margin, is the floor it must keep.
    dim = flat.clone()
    dim[0, channel(GREEN, SLOT), 0, THETA_D] = 0.02
    assert float(kept(edited, dim).holes[0]) == pytest.approx(0.01, abs=1e-6)
    assert float(kept(flat, flat).holes[0]) == 0
    with pytest.raises(ValueError, match="hole_margin"):
        TraversalPenalty(flat, hole_margin=-0.01)
    with pytest.raises(ValueError, match="traversal_hole_margin"):
        TrainConfig(traversal_hole_margin=float("nan"))


def test_pits_term_counts_a_fall_towards_the_centre_beyond_the_material_s_own(flat: torch.Tensor, penalty) -> None:
    pitted = flat.clone()
    pitted[0, channel(GREEN, SLOT), 0:3, THETA_D] = 0.1  # θh bins 0–2 fall 0.4 below the ring beyond them
    assert float(penalty(pitted, flat).pits[0]) == 0  # left out without a weight
    weighted = TraversalPenalty(flat, pit_weight=2.0)
    assert float(weighted(pitted, flat).pits[0]) == pytest.approx(2.0 * 3 * (0.4 - weighted.margin), abs=1e-5)
    assert pit_cells(pitted[0].numpy())[GREEN, SLOT, THETA_D]  # the plausibility check sees the same pit
    assert float(weighted(pitted, pitted).pits[0]) == 0  # the material's own pit is allowed
    # Only the centre is pushed up: the ring it falls from is held fixed.
    edited = pitted.clone().requires_grad_(True)
    weighted(edited, flat).pits.sum().backward()
    grad = edited.grad[0, channel(GREEN, SLOT), :, THETA_D]
    assert (grad[0:3] < 0).all() and (grad[3:] == 0).all()
    with pytest.raises(ValueError, match="pit_weight"):
        TraversalPenalty(flat, pit_weight=-1.0)
    with pytest.raises(ValueError, match="traversal_pit_weight"):
        TrainConfig(traversal_pit_weight=float("inf"))


def test_energy_is_the_log_excess_over_the_limit(flat, penalty) -> None:
    edited = flat + 0.3
    albedo = white_sky_albedo(edited[0].numpy())
    expected = ENERGY_SCALE * sum(max(0.0, math.log(a / penalty.albedo_limit)) for a in albedo)
    assert expected > 0
    assert float(penalty(edited, flat).energy[0]) == pytest.approx(expected, rel=1e-4)
    assert float(penalty(flat * 0.9, flat).energy[0]) == 0


def test_gradient_reaches_only_the_offending_entries(flat, penalty) -> None:
    edited = flat.clone()
    edited[0, channel(GREEN, SLOT), 0, THETA_D] = -0.25
    edited.requires_grad_(True)
    penalty(edited, flat).total().sum().backward()
    grad = edited.grad
    assert grad is not None
    assert float(grad[0, channel(GREEN, SLOT), 0, THETA_D]) == pytest.approx(-1.0)
    assert int((grad != 0).sum()) == 1


def test_penalty_stays_finite_for_extreme_outputs(flat, penalty) -> None:
    extreme = torch.cat([flat * 0 - 50.0, flat * 0 + 50.0, flat + 4.0])
    for dtype in (torch.float32, torch.float16):
        terms = penalty(extreme.to(dtype), torch.cat([flat] * 3).to(dtype))
        assert all(torch.isfinite(t).all() for t in (terms.inversion, terms.holes, terms.energy)), dtype
        assert float(terms.energy[1]) > 0 and float(terms.holes[0]) == 0  # all black: no hole


def test_traversed_codes_move_one_dimension_and_detach_mu() -> None:
    mu = torch.zeros(2, 4, requires_grad=True)
    codes = traversed_codes(mu, torch.tensor([1, 3]), torch.tensor([2.0, -1.5]))
    assert codes.tolist() == [[0, 2.0, 0, 0], [0, 0, 0, -1.5]]
    assert not codes.requires_grad


def test_config_validates_the_penalty_settings() -> None:
    for bad in (-1.0, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="traversal_weight"):
            TrainConfig(traversal_weight=bad)
    with pytest.raises(ValueError, match="traversal_range"):
        TrainConfig(traversal_range=0.0)


def test_penalty_draws_leave_the_plain_stream_alone() -> None:
    plain_config = TrainConfig(epochs=1, batch_size=4, seed=3)
    config = TrainConfig(epochs=1, batch_size=4, seed=3, traversal_weight=1.0, traversal_range=2.0)
    plain, drawn = list(_global_batches(10, plain_config, 0, 4)), list(_global_batches(10, config, 0, 4))
    assert "traverse_dim" not in plain[0]
    for key in ("rows", "permutation", "partner", "weight", "noise"):
        assert torch.equal(plain[0][key], drawn[0][key]), key
    dims = torch.cat([d["traverse_dim"] for d in drawn])
    offsets = torch.cat([d["traverse_offset"] for d in drawn])
    assert dims.min() >= 0 and dims.max() < 4
    assert offsets.abs().max() <= 2.0 and offsets.min() < 0 < offsets.max()


def test_traversed_codes_follow_a_direction() -> None:
    mu = torch.zeros(1, 2)
    direction = torch.tensor([[0.6, 0.8]])
    assert traversed_codes(mu, direction, torch.tensor([2.0])).tolist() == [[pytest.approx(1.2), pytest.approx(1.6)]]


def test_any_direction_draws_unit_vectors_after_the_axes_stream() -> None:
    axes = TrainConfig(epochs=1, batch_size=4, seed=3, traversal_weight=1.0)
    anywhere = TrainConfig(epochs=1, batch_size=4, seed=3, traversal_weight=1.0, traversal_directions="any")
    on_axes, drawn = list(_global_batches(40, axes, 0, 4)), list(_global_batches(40, anywhere, 0, 4))
    for key in ("rows", "noise", "traverse_offset"):
        assert torch.equal(on_axes[0][key], drawn[0][key]), key
    directions = torch.cat([d["traverse_dim"] for d in drawn])
    assert directions.shape == (40, 4)
    assert torch.allclose(directions.norm(dim=1), torch.ones(40))
    assert (directions.abs().amax(dim=1) < 0.99).float().mean() > 0.9  # not the axes
    assert (directions > 0).any(dim=0).all() and (directions < 0).any(dim=0).all()
    with pytest.raises(ValueError, match="traversal_directions"):
        TrainConfig(traversal_directions="diagonal")  # type: ignore[arg-type]


@pytest.mark.slow  # > 10 s on 2 cores
def test_a_run_with_the_penalty_logs_it_and_is_reproducible(tmp_path: Path) -> None:
    data = tmp_path / "analytic.h5"
    build_dataset(data, analytic_sources(random_count=5), source_kind="analytic", description="analytic test set",
                  validation_fraction=0.2, seed=0, progress=False)
    config = TrainConfig(epochs=2, batch_size=4, learning_rate=1e-3, warmup_epochs=1, eval_every=1,
                         checkpoint_every=1, seed=7, traversal_weight=1.0)
    plain = TrainConfig(**{**config.to_dict(), "traversal_weight": 0.0})
    for name, train_config in (("a", config), ("b", config), ("plain", plain)):
        train(data, tmp_path / name, model_config=TINY_CONFIG, train_config=train_config, progress=False)
    logs = {name: [json.loads(line) for line in (tmp_path / name / "log.jsonl").read_text().splitlines()]
            for name in ("a", "b", "plain")}
    assert [r["loss"] for r in logs["a"]] == [r["loss"] for r in logs["b"]]
    assert all(r["traversal"] == 0 for r in logs["plain"])
    assert all(math.isfinite(r["traversal"]) and r["traversal"] >= 0 for r in logs["a"])
    # The logged loss is the β-VAE objective plus the weighted penalty, which a tiny model at its start incurs.
    weight = beta_norm(config.beta, TINY_CONFIG.latent_dim)
    assert any(r["traversal"] > 0 for r in logs["a"])
    for record in logs["a"]:
        objective = record["recon"] + weight * record["kl"]
        assert record["loss"] == pytest.approx(objective + config.traversal_weight * record["traversal"], rel=1e-6)
    assert logs["a"][-1]["loss"] != logs["plain"][-1]["loss"]


def test_energy_keeps_a_gradient_on_saturated_peaks(flat, penalty) -> None:
    edited = flat.clone()
    edited[0, :, 0:3, :] = 6.0  # near-specular rows above the decode's ceiling (MAPPED_MAX = 5)
    edited.requires_grad_(True)
    terms = penalty(edited, flat)
    assert float(terms.energy[0].detach()) > 0
    terms.energy.sum().backward()
    assert edited.grad is not None and float(edited.grad[0, :, 0:3, :].abs().sum()) > 0


def test_penalty_moved_to_a_device_keeps_its_tensors_there(flat: torch.Tensor) -> None:
    """`to` moves the fixed masks and weights once (the trainer's device), and returns the penalty itself."""
    moved = TraversalPenalty(flat)
    assert moved.to("meta") is moved
    assert {t.device.type for t in (moved._cells, moved._near, moved._weights)} == {"meta"}
    terms = moved(torch.zeros(2, 63, 90, 90, device="meta"), torch.zeros(2, 63, 90, 90, device="meta"))
    assert terms.total().device.type == "meta" and terms.total().shape == (2,)
    on_cpu = TraversalPenalty(flat).to("cpu")
    assert float(on_cpu(flat[:1].clone(), flat[:1]).total()) == 0.0
