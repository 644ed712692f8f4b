"""The β-VAE networks (PyTorch): encoder, decoder and the two together.

Input and output are the 63 × 90 × 90 mapped slices of ``spec/conventions.md``
§6. The decoder's output is ``MAPPED_MAX · sigmoid(·)``, always inside the
mapped domain [0, MAPPED_MAX], so every decoded table is finite.
"""

from __future__ import annotations

import torch
from torch import nn

from brdfcodec.conventions import MAPPED_MAX, NETWORK_INPUT_SHAPE
from brdfcodec.models.config import ModelConfig

__all__ = ["BetaVAE", "Decoder", "Encoder"]

_IN_CHANNELS = NETWORK_INPUT_SHAPE[0]
_BOTTLENECK = 12  # 90 → 45 → 23 → 12 with three 3×3 stride-2 convolutions
_INITIAL_LOGIT = -2.5


def _norm(kind: str, channels: int) -> nn.Module:
    if kind == "batch":
        return nn.BatchNorm2d(channels)
    if kind == "group":
        return nn.GroupNorm(8, channels)
    return nn.Identity()


class ResidualBlock(nn.Module):
    """Two 3×3 stride-1 convolutions with a skip connection."""

    def __init__(self, channels: int, config: ModelConfig) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(channels, channels, 3, padding=1),
            _norm(config.norm, channels),
            nn.LeakyReLU(config.negative_slope),
            nn.Conv2d(channels, channels, 3, padding=1),
            _norm(config.norm, channels),
        )
        self.activation = nn.LeakyReLU(config.negative_slope)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.activation(x + self.body(x))


def _fc_stack(widths: list[int], slope: float) -> nn.Sequential:
    layers: list[nn.Module] = []
    for a, b in zip(widths[:-1], widths[1:], strict=True):
        layers += [nn.Linear(a, b), nn.LeakyReLU(slope)]
    return nn.Sequential(*layers)


class Encoder(nn.Module):
    """Mapped slices ``(B, 63, 90, 90)`` to the posterior ``(μ, log σ²)``, each ``(B, latent_dim)``."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        layers: list[nn.Module] = []
        channels = _IN_CHANNELS
        for out in config.encoder_channels:
            layers += [nn.Conv2d(channels, out, 3, stride=2, padding=1), _norm(config.norm, out),
                       nn.LeakyReLU(config.negative_slope)]
            channels = out
        layers += [ResidualBlock(channels, config) for _ in range(config.encoder_res_blocks)]
        self.features = nn.Sequential(*layers)
        flat = channels * _BOTTLENECK * _BOTTLENECK
        self.fc = _fc_stack([flat, *config.encoder_fc], config.negative_slope)
        self.head = nn.Linear(config.encoder_fc[-1] if config.encoder_fc else flat, 2 * config.latent_dim)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.fc(self.features(x).flatten(1))
        mu, logvar = self.head(h).chunk(2, dim=1)
        return mu, logvar


class Decoder(nn.Module):
    """Latent ``(B, latent_dim)`` to mapped slices ``(B, 63, 90, 90)`` in [0, MAPPED_MAX]."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        c0, c1, c2 = config.decoder_channels
        slope = config.negative_slope
        self.fc = _fc_stack([config.latent_dim, *config.decoder_fc, c0 * _BOTTLENECK * _BOTTLENECK], slope)
        self.blocks = nn.Sequential(*(ResidualBlock(c0, config) for _ in range(config.decoder_res_blocks)))
        self.upsample = nn.Sequential(
            nn.ConvTranspose2d(c0, c1, 3, stride=2, padding=1), _norm(config.norm, c1), nn.LeakyReLU(slope),  # 23
            nn.ConvTranspose2d(c1, c2, 3, stride=2, padding=1), _norm(config.norm, c2), nn.LeakyReLU(slope),  # 45
            nn.ConvTranspose2d(c2, _IN_CHANNELS, 4, stride=2, padding=1),  # 90
        )
        # Start near a typical mapped value (sigmoid(−2.5) · 5 ≈ 0.38) rather than the middle of the domain.
        with torch.no_grad():
            self.upsample[-1].bias.fill_(_INITIAL_LOGIT)

    def logits(self, z: torch.Tensor) -> torch.Tensor:
        """Pre-activation output, ``(B, 63, 90, 90)``."""
        c0 = self.config.decoder_channels[0]
        h = self.fc(z).view(-1, c0, _BOTTLENECK, _BOTTLENECK)
        return self.upsample(self.blocks(h))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return MAPPED_MAX * torch.sigmoid(self.logits(z))


class BetaVAE(nn.Module):
    """Encoder and decoder together.

    ``forward`` samples ``z = μ + σ·ε`` with the reparameterisation trick in
    training mode and uses ``z = μ`` in evaluation mode.
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        self.encoder = Encoder(config)
        self.decoder = Decoder(config)

    def forward(
        self, x: torch.Tensor, noise: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Return ``(reconstruction, μ, log σ²)``.

        Parameters
        ----------
        x : Tensor, shape (B, 63, 90, 90)
            Mapped inputs.
        noise : Tensor, shape (B, latent_dim), optional
            The ε of the reparameterisation in training mode (drawn here when
            not given; given by the trainer so that runs are reproducible
            across process counts).
        """
        mu, logvar = self.encoder(x)
        if self.training:
            eps = torch.randn_like(mu) if noise is None else noise
            z = mu + torch.exp(0.5 * logvar) * eps
        else:
            z = mu
        return self.decoder(z), mu, logvar
