"""The highlight guard of edited records' decode (spec/bvae-format.md §6 step 6; issue 41)."""

from __future__ import annotations

import numpy as np
import pytest

from brdfcodec.codec import BrdfDecoder
from brdfcodec.edit.latent_edits import traverse
from brdfcodec.edit.plausibility import inverted_cells, new_holes, pit_cells
from brdfcodec.representation.highlight import HIGHLIGHT_TOLERANCE, guard_highlights_mapped, window_valid_mask

GREEN, SLOT = 1, 10


def channel(colour: int, slot: int) -> int:
    return colour * 21 + slot


def test_a_pit_is_raised_to_within_tau_of_what_surrounds_it() -> None:
    mapped = np.full((63, 90, 90), 0.6, dtype=np.float32)
    c = channel(GREEN, SLOT)
    mapped[c, 0:2, 10] = 0.0  # a black pit under a lit flank
    mapped[c, 0:2, 11] = 0.2  # an inverted peak: 0.4 below its flank
    mapped[c, 0:2, 12] = 0.58  # within τ of the flank: left alone
    mapped[c, 0:21, 13] = 0.04  # a dim highlight whose centre is black: raised to half of it
    mapped[c, 0:2, 13] = 0.0
    mapped[c, 0:10, 14] = 0.0  # a wide black disc inside a lit ring (bins 10–20): the dot a sheet shows
    guarded = guard_highlights_mapped(mapped)
    assert guarded.dtype == np.float32
    np.testing.assert_allclose(guarded[c, 0:2, 10], 0.6 - HIGHLIGHT_TOLERANCE, rtol=1e-6)
    np.testing.assert_allclose(guarded[c, 0:2, 11], 0.6 - HIGHLIGHT_TOLERANCE, rtol=1e-6)
    np.testing.assert_array_equal(guarded[c, 0:2, 12], mapped[c, 0:2, 12])
    np.testing.assert_allclose(guarded[c, 0:2, 13], 0.02, rtol=1e-6)
    np.testing.assert_allclose(guarded[c, 0:10, 14], 0.6 - HIGHLIGHT_TOLERANCE, rtol=1e-6)
    changed = guarded != mapped
    assert changed[:, 20:].sum() == 0  # only θh bins 0–19 change
    assert changed.sum() == 2 * 3 + 10  # four cells of one channel: their raised entries
    assert not inverted_cells(guarded).any() and not pit_cells(guarded).any()
    assert not new_holes(np.full_like(mapped, 0.6), guarded).any()
    assert pit_cells(mapped)[GREEN, SLOT, [10, 11, 14]].all() and not pit_cells(mapped)[GREEN, SLOT, 12]
    np.testing.assert_array_equal(guard_highlights_mapped(guarded), guarded)  # idempotent


def test_values_below_the_horizon_are_neither_raised_nor_counted_and_peaks_are_left_alone() -> None:
    mapped = np.zeros((2, 63, 90, 90), dtype=np.float32)
    mapped[..., 4:7, :] = 1.0  # a lit flank over a black peak everywhere
    guarded = guard_highlights_mapped(mapped)
    valid = np.broadcast_to(window_valid_mask()[None, None, :, 0:2, :], (2, 3, 21, 2, 90))
    near = guarded.reshape(2, 3, 21, 90, 90)[..., 0:2, :]
    assert (near[valid] == np.float32(1 - HIGHLIGHT_TOLERANCE)).all() and (near[~valid] == 0).all()
    below = ~window_valid_mask()  # (21 slots, θh 0–20, θd): entries below the horizon stay as they are
    beyond = guarded.reshape(2, 3, 21, 90, 90)[..., :21, :][:, :, below]
    assert (beyond == mapped.reshape(2, 3, 21, 90, 90)[..., :21, :][:, :, below]).all()
    peaked = np.linspace(2.0, 0.1, 90, dtype=np.float32)[None, :, None] * np.ones((63, 1, 90), np.float32)
    np.testing.assert_array_equal(guard_highlights_mapped(peaked), peaked)


def test_the_guard_refuses_bad_arguments() -> None:
    with pytest.raises(ValueError, match="tolerance"):
        guard_highlights_mapped(np.zeros((63, 90, 90)), tolerance=-1)
    with pytest.raises(ValueError, match="shape"):
        guard_highlights_mapped(np.zeros((63, 90, 89)))


def test_edited_records_decode_guarded_and_others_as_encoded() -> None:
    """black-fabric at z8 +3σ: the network's decode inverts peaks and digs holes; the edit's decode does neither."""
    from brdfcodec.codec import MaterialLibrary
    from brdfcodec.examples import example_library

    decoder = BrdfDecoder()
    with MaterialLibrary(example_library(), decoder=decoder) as library:
        source = library.record("black-fabric")
    [edit] = traverse(source, 7, [3.0])
    before = decoder.mapped_record(source)
    raw = decoder.mapped_record(edit, energy_bound=False)
    assert inverted_cells(raw).any() and new_holes(before, raw).any() and pit_cells(raw).any()
    guarded = decoder.mapped_record(edit)
    assert not inverted_cells(guarded).any() and not new_holes(before, guarded).any()
    assert not (pit_cells(guarded) & ~pit_cells(before)).any()
    table = decoder.decode(edit, masked="zero")
    assert np.isfinite(table).all() and (table >= 0).all()
    unguarded = decoder.decode(edit, masked="zero", energy_bound=False)
    assert not np.array_equal(table, unguarded)
    np.testing.assert_array_equal(before, decoder.mapped_record(source, energy_bound=False))  # not an edit
