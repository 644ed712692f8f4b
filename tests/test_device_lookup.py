"""Values at direction pairs without tables (issue 51, item 1): ``BrdfDecoder.evaluate_tensor``.

Each value is the nearest-bin lookup of the decoded table (``representation.lookup`` of ``decode_many``'s table,
below-horizon bins 0), made from the kept slices alone; the bins are NumPy's.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import brdfcodec as bc
from brdfcodec.codec import BrdfDecoder
from brdfcodec.codec.device_lookup import merl_bins_tensor
from brdfcodec.edit.latent_edits import with_parameters
from brdfcodec.examples import example_library
from brdfcodec.format.bvae import LatentRecord
from brdfcodec.representation.coords import (
    directions_from_half_diff,
    half_diff_from_directions,
    phi_d_from_index,
    phi_d_index,
    theta_d_from_index,
    theta_d_index,
    theta_h_from_index,
    theta_h_index,
)
from brdfcodec.representation.lookup import lookup
from brdfcodec.representation.mask import horizon_mask


@pytest.fixture(scope="module")
def decoder() -> BrdfDecoder:
    return BrdfDecoder()


def directions(count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random pairs over the sphere (some below the horizon), grazing ones, a mirror pair and unnormalised ones."""
    rng = np.random.default_rng(seed)
    wi, wo = rng.standard_normal((count, 3)), rng.standard_normal((count, 3))
    wi[: count // 2, 2], wo[: count // 2, 2] = np.abs(wi[: count // 2, 2]), np.abs(wo[: count // 2, 2])
    wi[0], wo[0] = [0.3, 0.1, 0.9], [-0.3, -0.1, 0.9]  # mirror: θh = 0
    wi[1], wo[1] = [1.0, 0.0, 1e-4], [-1.0, 0.2, 1e-3]  # grazing
    wi[2] *= 1e3
    return wi, wo


def grid_directions() -> tuple[np.ndarray, np.ndarray]:
    """Pairs at the representative angles of MERL bins (the bins' lower edges: θh bin 1 starts at 1.9e-4 rad,
    where an arccos of z is off by more than the bins' tolerance), θd > 0, random φh."""
    h, d, p = np.meshgrid(np.arange(90), np.arange(1, 90, 3), np.arange(0, 180, 7), indexing="ij")
    phi_h = np.random.default_rng(8).uniform(-np.pi, np.pi, h.shape)
    wi, wo = directions_from_half_diff(theta_h_from_index(h), theta_d_from_index(d), phi_d_from_index(p), phi_h)
    return wi.reshape(-1, 3), wo.reshape(-1, 3)


@pytest.mark.parametrize("pairs", ["random", "grid"])
def test_the_bins_are_numpy_s(pairs: str) -> None:
    wi, wo = directions(20000, 1) if pairs == "random" else grid_directions()
    h, d, p, above = merl_bins_tensor(torch.from_numpy(wi), torch.from_numpy(wo))
    theta_h, theta_d, phi_d, _ = half_diff_from_directions(wi, wo)
    np.testing.assert_array_equal(h.numpy(), theta_h_index(theta_h))
    np.testing.assert_array_equal(d.numpy(), theta_d_index(theta_d))
    np.testing.assert_array_equal(p.numpy(), phi_d_index(phi_d))
    np.testing.assert_array_equal(above.numpy(), (wi[:, 2] > 1e-9) & (wo[:, 2] > 1e-9))


def test_values_are_the_decoded_table_s_nearest_bins(decoder: BrdfDecoder) -> None:
    rng = np.random.default_rng(4)
    plain = [LatentRecord(f"m{i}", rng.standard_normal(decoder.latent_dim), np.ones(decoder.latent_dim))
             for i in range(2)]
    with bc.MaterialLibrary(example_library(), decoder=decoder) as library:
        chrome = library.record("chrome")
    shifted = np.asarray(chrome.mu, dtype=np.float32).copy()
    shifted[3] -= 3.0  # chrome at z4 −3σ: an edit the highlight guard and the energy bound change
    edited = with_parameters(chrome, shifted, name="chrome.z4-3", edit={"op": "traverse"})
    assert decoder.energy_scale(edited) < 0.9
    records = [*plain, edited]
    wi, wo = directions(4000, 2)
    got = decoder.evaluate_tensor(records, wi, wo)
    assert got.dtype == torch.float32 and got.shape == (3, 4000, 3)
    valid = np.broadcast_to(horizon_mask(), (3, 90, 90, 180))
    for values, table in zip(got.numpy(), decoder.decode_many(records, masked="zero"), strict=True):
        want = lookup(table, wi, wo, mask=valid)
        np.testing.assert_allclose(values, want, rtol=1e-6, atol=1e-12)
    assert (got[:, 4000 // 2 :] == 0).any() and (got > 0).any()  # below-horizon pairs, and values


def test_directions_per_material_and_codes(decoder: BrdfDecoder) -> None:
    codes = np.random.default_rng(6).standard_normal((2, decoder.latent_dim)).astype(np.float32)
    wi, wo = directions(50, 3)
    other_wi, other_wo = directions(50, 9)
    per = decoder.evaluate_tensor(codes, np.stack([wi, other_wi]), np.stack([wo, other_wo]))  # (B, N, 3) each
    shared_first = decoder.evaluate_tensor(codes, wi, wo)
    shared_second = decoder.evaluate_tensor(codes, other_wi, other_wo)
    torch.testing.assert_close(per[0], shared_first[0])
    torch.testing.assert_close(per[1], shared_second[1])
    assert not torch.equal(per[1], shared_first[1])  # material 1 read its own directions
    torch.testing.assert_close(decoder.evaluate_tensor(codes, wo, wi), shared_first)  # reciprocity: the same bin
    one = decoder.evaluate_tensor(torch.from_numpy(codes), wi[5], wo[5])
    assert one.shape == (2, 1, 3)
    torch.testing.assert_close(one[:, 0], shared_first[:, 5])
    assert decoder.evaluate_tensor([], wi, wo).shape == (0, 50, 3)


def test_directions_per_material_follow_their_material_across_network_batches(decoder: BrdfDecoder) -> None:
    """Five materials, each with its own directions: the lookup runs a network batch of materials at a time
    (BrdfDecoder.network_batch, 2 on the CPU), each batch reading its own rows of the directions."""
    codes = np.random.default_rng(7).standard_normal((5, decoder.latent_dim)).astype(np.float32)
    pairs = [directions(40, seed) for seed in range(11, 16)]
    per = decoder.evaluate_tensor(codes, np.stack([w for w, _ in pairs]), np.stack([w for _, w in pairs]))
    assert per.shape == (5, 40, 3)
    for i, (wi, wo) in enumerate(pairs):
        torch.testing.assert_close(per[i], decoder.evaluate_tensor(codes[i : i + 1], wi, wo)[0])


def test_bad_directions_are_refused_with_a_value_error(decoder: BrdfDecoder) -> None:
    codes = np.zeros((2, decoder.latent_dim), dtype=np.float32)
    up = np.array([[0.0, 0.0, 1.0]])
    for wi, match in [(np.zeros((1, 3)), "zero vectors"), (np.full((1, 3), np.nan), "NaN"),
                      (np.ones((1, 2)), "3-vectors"), (np.ones((3, 4, 3)), "B = 2"), (np.ones((2, 2, 2, 3)), "shape")]:
        with pytest.raises(ValueError, match=match):
            decoder.evaluate_tensor(codes, wi, up)
    with pytest.raises(ValueError, match="broadcast"):
        decoder.evaluate_tensor(codes, np.ones((4, 3)), np.ones((5, 3)))
    with pytest.raises(ValueError, match="finite"):
        decoder.evaluate_tensor(np.full((1, decoder.latent_dim), np.inf), up, up)
