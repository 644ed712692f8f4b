"""Configuration of the β-VAE: every size is a field, so model variants are one line apart."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from typing import Any, Literal

__all__ = ["CONFIG_BOUNDS", "PAPER_CONFIG", "SMALL_CONFIG", "TINY_CONFIG", "ModelConfig"]

NormKind = Literal["batch", "group", "none"]


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of the β-VAE of the paper, with sizes as parameters.

    The encoder applies three 3×3 stride-2 convolutions (90 → 45 → 23 → 12),
    ``encoder_res_blocks`` residual blocks at 12×12, then fully connected
    layers to μ and log σ². The decoder mirrors it: fully connected layers to
    ``decoder_channels[0] × 12 × 12``, ``decoder_res_blocks`` residual
    blocks, two 3×3 stride-2 transposed convolutions (12 → 23 → 45) and a
    last 4×4 one (45 → 90) to the 63 mapped slices.

    Attributes
    ----------
    latent_dim : int
        Size of the latent code (8 in the paper).
    encoder_channels : tuple of int
        Output channels of the three stride-2 convolutions.
    encoder_res_blocks : int
        Residual blocks after them (9 in the paper).
    encoder_fc : tuple of int
        Hidden widths of the fully connected layers before μ, log σ².
    decoder_fc : tuple of int
        Hidden widths of the fully connected layers after z.
    decoder_channels : tuple of int
        Channels at 12×12, 23×23 and 45×45.
    decoder_res_blocks : int
        Residual blocks at 12×12 (3 in the paper).
    norm : {"batch", "group", "none"}
        Normalisation after each convolution ("batch" in the paper; "group"
        does not depend on the batch, see the model card).
    negative_slope : float
        Slope of the leaky ReLU.
    linear_basis : bool
        Add a linear path: the encoder's μ starts as the whitened PCA
        coefficients of the input and the decoder's output as the PCA
        reconstruction (a basis of ``latent_dim`` components over the valid
        entries, fitted on the training split and stored in float16); the
        convolutional paths learn non-linear corrections on top, starting
        from zero. Without it the decoder is the paper's convolutional stack
        with a ``MAPPED_MAX · sigmoid`` output.
    """

    latent_dim: int = 8
    encoder_channels: tuple[int, int, int] = (64, 64, 64)
    encoder_res_blocks: int = 2
    encoder_fc: tuple[int, ...] = (256,)
    decoder_fc: tuple[int, ...] = (192,)
    decoder_channels: tuple[int, int, int] = (64, 64, 64)
    decoder_res_blocks: int = 2
    norm: NormKind = "group"
    negative_slope: float = 0.01
    linear_basis: bool = False

    def __post_init__(self) -> None:
        if self.latent_dim < 1:
            raise ValueError(f"latent_dim must be ≥ 1, got {self.latent_dim}")
        for name in ("encoder_channels", "decoder_channels"):
            value = getattr(self, name)
            if len(value) != 3 or min(value) < 1:
                raise ValueError(f"{name} must be three positive channel counts, got {value}")
        if self.norm not in ("batch", "group", "none"):
            raise ValueError(f"norm must be 'batch', 'group' or 'none', got {self.norm!r}")
        if self.norm == "group" and any(c % 8 for c in (*self.encoder_channels, *self.decoder_channels)):
            raise ValueError("with norm='group' every channel count must be a multiple of 8")

    def to_json(self) -> str:
        """Canonical JSON (sorted keys), as stored beside the weights."""
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModelConfig:
        """Inverse of :func:`dataclasses.asdict`, for a config read from a file: every field's type and bounds
        are checked (:data:`CONFIG_BOUNDS`) before anything is built; unknown keys are an error.

        Raises
        ------
        ValueError
            Not a mapping, an unknown key, a value of the wrong type (a boolean is not an integer) or out of
            its bounds.
        """
        if not isinstance(data, dict):
            raise ValueError(f"a model config is a JSON object, got {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(str(key) for key in set(data) - known)
        if unknown:
            raise ValueError(f"unknown model config keys {unknown}")
        values = {key: _checked_field(key, value) for key, value in data.items()}
        return cls(**values)


#: What a config read from a file may hold (``spec/model.md`` §3): integer ranges of the sizes, how many
#: fully connected layers, the leaky ReLU's slope. Far above any trained model's, they keep a crafted
#: ``model.json`` from building a network of terabytes or thousands of layers.
CONFIG_BOUNDS: dict[str, tuple[float, float]] = {
    "latent_dim": (1, 1024),
    "channels": (1, 1024),
    "res_blocks": (0, 64),
    "fc_width": (1, 16384),
    "fc_layers": (0, 8),
    "negative_slope": (0.0, 1.0),
}


def _bounded_int(key: str, value: object, bound: str) -> int:
    low, high = CONFIG_BOUNDS[bound]
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"config {key} must be an integer, got {value!r}")
    if not low <= value <= high:
        raise ValueError(f"config {key} must be in [{low:g}, {high:g}], got {value}")
    return value


def _int_list(key: str, value: object, bound: str, count: tuple[int, int]) -> tuple[int, ...]:
    if not isinstance(value, list | tuple):
        raise ValueError(f"config {key} must be a list of integers, got {value!r}")
    if not count[0] <= len(value) <= count[1]:
        wanted = str(count[0]) if count[0] == count[1] else f"{count[0]} to {count[1]}"
        raise ValueError(f"config {key} must hold {wanted} integers, got {len(value)}")
    return tuple(_bounded_int(key, item, bound) for item in value)


def _checked_field(key: str, value: object) -> object:
    """One field of a config from a file, type- and bound-checked (tuples for lists)."""
    fc_layers = (int(CONFIG_BOUNDS["fc_layers"][0]), int(CONFIG_BOUNDS["fc_layers"][1]))
    if key == "latent_dim":
        return _bounded_int(key, value, "latent_dim")
    if key in ("encoder_channels", "decoder_channels"):
        return _int_list(key, value, "channels", (3, 3))
    if key in ("encoder_res_blocks", "decoder_res_blocks"):
        return _bounded_int(key, value, "res_blocks")
    if key in ("encoder_fc", "decoder_fc"):
        return _int_list(key, value, "fc_width", fc_layers)
    if key == "norm":
        if value not in ("batch", "group", "none"):
            raise ValueError(f"config norm must be 'batch', 'group' or 'none', got {value!r}")
        return value
    if key == "negative_slope":
        low, high = CONFIG_BOUNDS["negative_slope"]
        if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
            raise ValueError(f"config negative_slope must be a number in [{low:g}, {high:g}], got {value!r}")
        return float(value)
    if key == "linear_basis":
        if not isinstance(value, bool):
            raise ValueError(f"config linear_basis must be true or false, got {value!r}")
        return value
    raise ValueError(f"unknown model config key {key!r}")


#: The paper's sizes as far as its text gives them (78.9 MB in the paper).
PAPER_CONFIG = ModelConfig(
    encoder_channels=(128, 128, 64),
    encoder_res_blocks=9,
    encoder_fc=(1024, 256),
    decoder_fc=(256, 1024),
    decoder_channels=(64, 128, 128),
    decoder_res_blocks=3,
    norm="batch",
)

#: Default: the paper's layout at small widths plus the linear basis; a decoder a fraction of the paper's size.
SMALL_CONFIG = ModelConfig(decoder_channels=(32, 32, 32), decoder_fc=(128,), linear_basis=True)

#: For tests: seconds to build and run.
TINY_CONFIG = ModelConfig(
    encoder_channels=(8, 8, 8),
    encoder_res_blocks=1,
    encoder_fc=(16,),
    decoder_fc=(16,),
    decoder_channels=(8, 8, 8),
    decoder_res_blocks=1,
)
