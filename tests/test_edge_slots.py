"""Edge slots: kept φd slots below the horizon that the interpolation carries into valid bins
(``representation/edge_slots.py``), and training the decoder towards their fitted values (``--edge-slots``)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from brdfcodec.conventions import KEPT_PHI_D_SLICES, MAPPED_MAX
from brdfcodec.io.merl import MerlBRDF
from brdfcodec.models.config import TINY_CONFIG
from brdfcodec.representation.edge_slots import edge_slot_targets
from brdfcodec.representation.layout import from_network_layout, interpolate_slices, select_kept_slices
from brdfcodec.representation.mapping import map_values
from brdfcodec.representation.network_io import network_input_from_table
from brdfcodec.training.config import TrainConfig
from brdfcodec.training.trainer import _with_edge_slots, train


def _interpolation_error(table: MerlBRDF, kept_network: np.ndarray) -> float:
    """Mapped RelAE over the valid bins of the table interpolated from kept slices (network layout)."""
    mapped = map_values(np.where(table.mask, table.values, 0.0))
    estimate = interpolate_slices(from_network_layout(kept_network).astype(np.float64))
    return float(np.abs(estimate - mapped)[table.mask].sum() / np.abs(mapped)[table.mask].sum())


def test_edge_slots_lie_below_the_horizon_next_to_valid_bins(analytic_tables: dict[str, MerlBRDF]) -> None:
    table = analytic_tables["gold"]
    targets, weights = edge_slot_targets(table.values, table.mask)
    inputs, valid = network_input_from_table(table.values, table.mask)
    assert targets.shape == weights.shape == valid.shape and targets.dtype == weights.dtype == np.float32
    edge = weights > 0
    assert edge.any() and not (edge & valid).any()  # only slots the input leaves out
    assert np.all((weights >= 0) & (weights <= 1)) and np.all((targets >= 0) & (targets <= MAPPED_MAX))
    assert not targets[~edge].any()
    # every edge slot has a valid bin between it and a valid neighbour slot, in its (colour, θh, θd) cell
    kept_valid = select_kept_slices(table.mask)
    slot_edge = from_network_layout(edge)
    for c, h, d, k in zip(*np.nonzero(slot_edge), strict=True):
        sides = [(k - 1, range(KEPT_PHI_D_SLICES[k - 1] + 1, KEPT_PHI_D_SLICES[k]))] if k > 0 else []
        sides += [(k + 1, range(KEPT_PHI_D_SLICES[k] + 1, KEPT_PHI_D_SLICES[k + 1]))] if k < 20 else []
        assert any(kept_valid[c, h, d, other] and table.mask[c, h, d, list(bins)].any() for other, bins in sides)


def test_edge_targets_lower_the_interpolation_floor(analytic_tables: dict[str, MerlBRDF]) -> None:
    """The source's own kept slices, interpolated: with 0 at the slots below the horizon (the network input) the
    horizon band's bins run towards 0; with the edge targets they follow the material (measured: 0.0055 to below
    0.0001 on gold)."""
    for name in ("gold", "red-plastic"):
        table = analytic_tables[name]
        inputs, _ = network_input_from_table(table.values, table.mask)
        targets, weights = edge_slot_targets(table.values, table.mask)
        before = _interpolation_error(table, inputs)
        after = _interpolation_error(table, np.where(weights > 0, targets, inputs))
        assert after < 0.1 * before, (name, before, after)


def test_a_slot_past_a_straight_run_continues_it() -> None:
    """Mapped values linear in φd across the gap before the horizon: the fitted slot continues the line."""
    values = np.full((3, 90, 90, 180), -1.0)
    phi = np.arange(180, dtype=np.float64)
    line = 0.5 + 0.01 * phi  # mapped units
    from brdfcodec.representation.mapping import unmap_values

    stored = unmap_values(np.broadcast_to(line, (3, 180)).copy(), channel_axis=0)
    values[:, 40, 40, :50] = stored[:, :50]  # valid up to bin 49: kept slot 45 valid, 54 not, bins 46–49 valid
    targets, weights = edge_slot_targets(values, values >= 0)
    slot = KEPT_PHI_D_SLICES.index(54)
    fitted = from_network_layout(targets)[:, 40, 40, slot]
    np.testing.assert_allclose(fitted, line[54], rtol=1e-5)
    np.testing.assert_allclose(from_network_layout(weights)[:, 40, 40, slot], (1 + 2 + 3 + 4) / 9 / 9, rtol=1e-6)


def test_bad_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match="shape"):
        edge_slot_targets(np.zeros((3, 90, 90, 179)), np.ones((3, 90, 90, 179), bool))


def test_the_option_is_stored_and_read() -> None:
    assert TrainConfig().edge_slots is False
    assert TrainConfig.from_dict(json.loads(json.dumps({"edge_slots": True}))).edge_slots is True


def test_a_batch_takes_the_edge_targets_where_the_input_leaves_a_slot_out() -> None:
    """The loss's target and weights of a batch (no blend: a material with itself, colours kept): the edge target
    and its weight (its square root for the squared error) at the slots the mask leaves out, the input and 1 at
    the valid entries, even where an edge weight is given there too."""
    generator = torch.Generator().manual_seed(0)
    x = torch.rand(2, 63, 90, 90, generator=generator)
    m = torch.rand(2, 63, 90, 90, generator=generator) > 0.3
    edge_targets = torch.rand(2, 63, 90, 90, generator=generator)
    edge_weights = torch.where(torch.rand(2, 63, 90, 90, generator=generator) > 0.9, 0.25, 0.0)
    data = SimpleNamespace(edge_targets=edge_targets, edge_weights=edge_weights)
    rows = torch.tensor([0, 1])
    for recon, expected_weight in (("l1", 0.25), ("l2", 0.5)):
        target, weights = _with_edge_slots(data, x, m, rows, rows, torch.ones(2), torch.zeros(2, dtype=torch.long),
                                           recon)
        edge = (edge_weights > 0) & ~m
        assert torch.allclose(target[edge], edge_targets[edge], atol=1e-6)  # the blend of a target with itself
        assert torch.equal(target[~edge], x[~edge])
        assert torch.equal(weights[m], torch.ones(int(m.sum())))
        assert torch.allclose(weights[edge], torch.full((int(edge.sum()),), expected_weight))
        assert not weights[~edge & ~m].any()


def test_a_dataset_without_tables_is_refused(tmp_path: Path) -> None:
    from brdfcodec.datasets.hdf5 import build_dataset
    from brdfcodec.datasets.sources import analytic_sources
    from brdfcodec.errors import DatasetError

    path = build_dataset(tmp_path / "no-tables.h5", analytic_sources(random_count=3), description="no tables",
                         source_kind="analytic", validation_fraction=0.34, include_tables=False, progress=False)
    with pytest.raises(DatasetError, match="edge-slots needs full tables"):
        train(path, tmp_path / "run", model_config=TINY_CONFIG,
              train_config=TrainConfig(epochs=1, batch_size=2, edge_slots=True), progress=False)
    assert not (tmp_path / "run" / "checkpoint.pt").exists()


@pytest.mark.slow  # about half a minute on 2 cores
def test_a_run_records_the_option(analytic_training_set: Path, tmp_path: Path) -> None:
    """A short run with the option trains and says so in its configuration (what the option does to a model is
    measured in reports/edge-slots/, not in a run of a few steps)."""
    train(analytic_training_set, tmp_path / "edges", model_config=TINY_CONFIG,
          train_config=TrainConfig(epochs=2, batch_size=4, warmup_epochs=1, eval_every=2, checkpoint_every=2,
                                   seed=7, keep="last", edge_slots=True), progress=False)
    stored = json.loads((tmp_path / "edges" / "run.json").read_text())["train_config"]
    assert TrainConfig.from_dict(stored).edge_slots is True
    log = [json.loads(line) for line in (tmp_path / "edges" / "log.jsonl").read_text().splitlines()]
    assert log and all(np.isfinite(row["loss"]) for row in log)
