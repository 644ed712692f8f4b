"""The decoder as ``spec/model.md`` §1.1 specifies it, written in NumPy from that text alone.

:func:`spec_decode` follows the spec's steps 1–6 (fully connected layers, reshape, residual blocks,
upsampling, output, clamp) with nothing from ``brdfcodec.models.network``: it reads the tensors of a
``decoder.safetensors`` file (or a state dict) by the names the spec gives, checks their shapes against
the config, and computes in binary64. It must reproduce brdfcodec's PyTorch decodes of the shipped models,
of decoders of other configurations (other widths, no hidden layer, BatchNorm, no normalisation, the
sigmoid output), and the spec's rule for huge latents, so that the spec and the code cannot drift apart.
"""

from __future__ import annotations

import json
from collections.abc import Mapping

import numpy as np
import pytest
from safetensors.numpy import load_file

from brdfcodec.conventions import KEPT_PHI_D_SLICES
from brdfcodec.models.registry import package_model_folder
from brdfcodec.representation.mask import horizon_mask

SHIPPED = ("default", "nbrdf-proxy-small-v1", "nbrdf-proxy-small-v2")
TOLERANCE = 1e-4  # mapped units; the spec says a binary64 evaluation agrees within it
LATENT_CLIP = 1e3  # spec/model.md §1.1 step 0: each coordinate clipped to ±1e3 before the network


# ---------------------------------------------------------------------------------------------------------
# The spec's decoder (spec/model.md §1.1), binary64
# ---------------------------------------------------------------------------------------------------------

def _lrelu(x: np.ndarray, slope: float) -> np.ndarray:
    return np.where(x >= 0, x, slope * x)


def _conv3(x: np.ndarray, w: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross-correlation, 3×3, stride 1, zero padding 1: y[o,i,j] = b[o] + Σ W[o,c,u,v] x[c,i+u−1,j+v−1]."""
    c, h, wd = x.shape
    padded = np.zeros((c, h + 2, wd + 2))
    padded[:, 1:-1, 1:-1] = x
    out = np.zeros((w.shape[0], h, wd))
    for u in range(3):
        for v in range(3):
            out += np.einsum("oc,chw->ohw", w[:, :, u, v], padded[:, u : u + h, v : v + wd])
    return out + b[:, None, None]


def _conv_transpose(x: np.ndarray, w: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Stride 2, padding 1: scatter into the full (H−1)·2 + k grid, drop one row and column on each side."""
    _, h, wd = x.shape
    k = w.shape[2]
    full = np.zeros((w.shape[1], (h - 1) * 2 + k, (wd - 1) * 2 + k))
    for u in range(k):
        for v in range(k):
            full[:, u : u + 2 * h - 1 : 2, v : v + 2 * wd - 1 : 2] += np.einsum("co,chw->ohw", w[:, :, u, v], x)
    rows, cols = (h - 1) * 2 - 2 + k, (wd - 1) * 2 - 2 + k
    return full[:, 1 : 1 + rows, 1 : 1 + cols] + b[:, None, None]


def _norm(x: np.ndarray, t: Mapping[str, np.ndarray], prefix: str, kind: str) -> np.ndarray:
    if kind == "none":
        return x
    gamma, beta = t[f"{prefix}.weight"][:, None, None], t[f"{prefix}.bias"][:, None, None]
    if kind == "batch":
        mean, var = t[f"{prefix}.running_mean"][:, None, None], t[f"{prefix}.running_var"][:, None, None]
        return (x - mean) / np.sqrt(var + 1e-5) * gamma + beta
    groups = x.reshape(8, -1)  # 8 groups of C/8 consecutive channels
    m = groups.mean(axis=1, keepdims=True)
    v = ((groups - m) ** 2).mean(axis=1, keepdims=True)  # population variance
    return ((groups - m) / np.sqrt(v + 1e-5)).reshape(x.shape) * gamma + beta


def valid_positions() -> np.ndarray:
    """Flat positions 8100·k + 90·i + j of (63, 90, 90) whose bin (i, j, KEPT[k mod 21]) is above the horizon."""
    kept = horizon_mask()[:, :, list(KEPT_PHI_D_SLICES)]  # (θh, θd, kept slot): conventions §5 rule 1
    per_channel = np.stack([kept[:, :, k % 21] for k in range(63)])
    return np.flatnonzero(per_channel)


def expected_shapes(config: Mapping) -> dict[str, tuple[int, ...]]:
    """Every tensor spec/model.md §1.1 names, with its shape."""
    m, fc = config["latent_dim"], list(config["decoder_fc"])
    c0, c1, c2 = config["decoder_channels"]
    widths = [m, *fc, c0 * 144]
    shapes: dict[str, tuple[int, ...]] = {}
    for i in range(len(widths) - 1):
        shapes[f"fc.{2 * i}.weight"] = (widths[i + 1], widths[i])
        shapes[f"fc.{2 * i}.bias"] = (widths[i + 1],)

    def norm(prefix: str, c: int) -> None:
        if config["norm"] == "none":
            return
        names = ("weight", "bias") + (("running_mean", "running_var") if config["norm"] == "batch" else ())
        shapes.update({f"{prefix}.{n}": (c,) for n in names})

    for r in range(config["decoder_res_blocks"]):
        for conv, nrm in ((0, 1), (3, 4)):
            shapes[f"blocks.{r}.body.{conv}.weight"] = (c0, c0, 3, 3)
            shapes[f"blocks.{r}.body.{conv}.bias"] = (c0,)
            norm(f"blocks.{r}.body.{nrm}", c0)
    for conv, nrm, cin, cout, k in ((0, 1, c0, c1, 3), (3, 4, c1, c2, 3), (6, None, c2, 63, 4)):
        shapes[f"upsample.{conv}.weight"] = (cin, cout, k, k)
        shapes[f"upsample.{conv}.bias"] = (cout,)
        if nrm is not None:
            norm(f"upsample.{nrm}", cout)
    if config["linear_basis"]:
        e = len(valid_positions())
        shapes["basis_mean"] = (e,)
        shapes["basis_components"] = (m, e)
    return shapes


def spec_decode(z: np.ndarray, tensors: Mapping[str, np.ndarray], config: Mapping) -> np.ndarray:
    """Mapped slices (63, 90, 90) in [0, 5] of one latent, steps 1–6 of spec/model.md §1.1 (binary64)."""
    z = np.clip(np.asarray(z, dtype=np.float32).astype(np.float64), -LATENT_CLIP, LATENT_CLIP)  # binary32, step 0
    t = {k: np.asarray(v, dtype=np.float64) for k, v in tensors.items()}  # F16 widened
    s, kind = config["negative_slope"], config["norm"]
    c0 = config["decoder_channels"][0]
    h = z
    for i in range(len(config["decoder_fc"]) + 1):  # 1. every fully connected layer, then leaky ReLU
        h = _lrelu(t[f"fc.{2 * i}.weight"] @ h + t[f"fc.{2 * i}.bias"], s)
    h = h.reshape(c0, 12, 12)  # 2.
    for r in range(config["decoder_res_blocks"]):  # 3. leaky ReLU after the residual sum
        p = f"blocks.{r}.body"
        u = _lrelu(_norm(_conv3(h, t[f"{p}.0.weight"], t[f"{p}.0.bias"]), t, f"{p}.1", kind), s)
        u = _norm(_conv3(u, t[f"{p}.3.weight"], t[f"{p}.3.bias"]), t, f"{p}.4", kind)
        h = _lrelu(h + u, s)
    for conv, nrm in ((0, 1), (3, 4)):  # 4.
        h = _conv_transpose(h, t[f"upsample.{conv}.weight"], t[f"upsample.{conv}.bias"])
        h = _lrelu(_norm(h, t, f"upsample.{nrm}", kind), s)
    o = _conv_transpose(h, t["upsample.6.weight"], t["upsample.6.bias"])
    if config["linear_basis"]:  # 5.
        u = o.reshape(-1).copy()
        u[valid_positions()] += t["basis_mean"] + z @ t["basis_components"]
        u = u.reshape(o.shape)
    else:
        u = 5.0 / (1.0 + np.exp(-o))
    return np.clip(np.nan_to_num(u, nan=0.0), 0.0, 5.0)  # 6.


# ---------------------------------------------------------------------------------------------------------
# Tests
# ---------------------------------------------------------------------------------------------------------

def _shipped(name: str) -> tuple[dict[str, np.ndarray], dict]:
    folder = package_model_folder(name)
    config = json.loads((folder / "model.json").read_text())["config"]
    return load_file(str(folder / "decoder.safetensors")), config


def _torch_decode(name: str, codes: np.ndarray) -> np.ndarray:
    from brdfcodec.codec import BrdfDecoder

    return BrdfDecoder(package_model_folder(name)).decode_mapped(codes)


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_weight_file_holds_what_the_spec_names(name: str) -> None:
    tensors, config = _shipped(name)
    assert {k: tuple(v.shape) for k, v in tensors.items()} == expected_shapes(config)
    assert tensors["basis_mean"].dtype == np.float16 and tensors["fc.0.weight"].dtype == np.float32
    assert len(valid_positions()) == 387_378


@pytest.mark.parametrize("name", [SHIPPED[0], *(pytest.param(n, marks=pytest.mark.slow) for n in SHIPPED[1:])])
def test_spec_decoder_reproduces_shipped_model(name: str) -> None:
    tensors, config = _shipped(name)
    rng = np.random.default_rng(7)
    codes = np.concatenate([rng.normal(size=(2, 8)), 3.0 * rng.normal(size=(1, 8)), np.zeros((1, 8))])
    codes = codes.astype(np.float32)
    got = _torch_decode(name, codes)
    for code, decoded in zip(codes, got, strict=True):
        want = spec_decode(code, tensors, config)
        assert 0.01 < want.mean() < 5.0  # a real material, not a trivial agreement
        np.testing.assert_allclose(decoded, want, rtol=0, atol=TOLERANCE)


def test_spec_decoder_on_huge_latents() -> None:
    """Latents far outside the prior (1e5, 1e19, 1e23, the largest binary32) decode as their clip to ±1e3 does:
    saturated, finite, the same for every magnitude beyond the bound."""
    tensors, config = _shipped("default")
    codes = np.zeros((5, 8), dtype=np.float32)
    codes[0, 0] = 1e5
    codes[1, 3] = -1e19
    codes[2, 5] = 2e23
    codes[3, :] = np.float32(3.4e38) * np.array([1, -1, 1, -1, 1, -1, 1, -1], dtype=np.float32)
    codes[4, :] = LATENT_CLIP * np.array([1, -1, 1, -1, 1, -1, 1, -1], dtype=np.float32)
    got = _torch_decode("default", codes)
    for code, decoded in zip(codes, got, strict=True):
        want = spec_decode(code, tensors, config)
        np.testing.assert_allclose(decoded, want, rtol=0, atol=TOLERANCE)
    # beyond the bound, the bound (each decoded alone: in batches of another size the network may round otherwise)
    assert np.array_equal(_torch_decode("default", codes[3:4]), _torch_decode("default", codes[4:5]))
    assert all(g.max() > 1.0 for g in got)  # saturated network values, not an all-zero output


@pytest.mark.parametrize(
    "fc, blocks, norm, linear",
    [((), 1, "group", False), ((24, 40), 3, "batch", False), ((16,), 0, "none", True), ((16,), 2, "batch", True)],
)
@pytest.mark.slow
def test_spec_decoder_matches_other_configurations(fc: tuple[int, ...], blocks: int, norm: str, linear: bool) -> None:
    """Random weights in other shapes: the spec's layer list holds for every configuration, not one model."""
    import torch

    from brdfcodec.models.config import ModelConfig
    from brdfcodec.models.network import Decoder  # the implementation under test, not used by spec_decode

    config = ModelConfig(latent_dim=5, decoder_fc=fc, decoder_channels=(16, 8, 24), decoder_res_blocks=blocks,
                         norm=norm, negative_slope=0.05, linear_basis=linear)  # type: ignore[arg-type]
    torch.manual_seed(0)
    decoder = Decoder(config).eval()
    with torch.no_grad():
        for name, value in decoder.state_dict().items():
            if value.is_floating_point():  # the linear-basis init zeroes the last layer: give every tensor values
                scale = 0.3 if "basis" in name else 0.5
                value.copy_((torch.rand_like(value.float()) * (1.0 if "running_var" in name else 2.0) - (
                    0.0 if "running_var" in name else 1.0)) * scale + (0.5 if "running_var" in name else 0.0))
    tensors = {k: v.numpy() for k, v in decoder.state_dict().items() if k != "num_batches_tracked"
               and not k.endswith("num_batches_tracked")}
    as_json = json.loads(config.to_json())
    assert {k: tuple(v.shape) for k, v in tensors.items()} == expected_shapes(as_json)
    codes = np.random.default_rng(1).normal(size=(3, 5)).astype(np.float32)
    with torch.no_grad():
        got = decoder(torch.from_numpy(codes)).numpy()
    got = np.clip(np.nan_to_num(got), 0.0, 5.0)
    for code, decoded in zip(codes, got, strict=True):
        want = spec_decode(code, tensors, as_json)
        assert 0.0 < want.mean() < 5.0
        np.testing.assert_allclose(decoded, want, rtol=0, atol=TOLERANCE)
