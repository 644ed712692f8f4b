"""The β-VAE networks (PyTorch): encoder, decoder and the two together.

Input and output are the 63 × 90 × 90 mapped slices of ``spec/conventions.md``
§6. The decoder's output is ``MAPPED_MAX · sigmoid(·)``, always inside the
mapped domain [0, MAPPED_MAX], so every decoded table is finite.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from brdfcodec.conventions import LATENT_LIMIT, MAPPED_MAX, NETWORK_INPUT_SHAPE
from brdfcodec.models.config import ModelConfig
from brdfcodec.models.pca import fit_pca
from brdfcodec.representation import to_network_layout
from brdfcodec.representation.mask import kept_slice_horizon_mask

__all__ = ["BetaVAE", "Decoder", "Encoder", "initialise_linear_basis", "linear_path_trainable", "valid_input_index"]

_IN_CHANNELS = NETWORK_INPUT_SHAPE[0]
_BOTTLENECK = 12  # 90 → 45 → 23 → 12 with three 3×3 stride-2 convolutions
_INITIAL_LOGIT = -2.5


def valid_input_index() -> torch.Tensor:
    """Flat indices of the entries of a (63, 90, 90) input that are above the horizon."""
    mask = to_network_layout(kept_slice_horizon_mask()[None].repeat(3, axis=0))
    return torch.from_numpy(mask.reshape(-1).nonzero()[0])


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
        if config.linear_basis:
            n_valid = int(valid_input_index().numel())
            self.register_buffer("valid_index", valid_input_index(), persistent=False)
            self.register_buffer("basis_mean", torch.zeros(n_valid))
            self.register_buffer("basis_projection", torch.zeros(config.latent_dim, n_valid))
            with torch.no_grad():  # the non-linear path starts as a zero correction, σ small
                self.head.weight.zero_()
                self.head.bias.zero_()
                self.head.bias[config.latent_dim :] = -8.0

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.fc(self.features(x).flatten(1))
        mu, logvar = self.head(h).chunk(2, dim=1)
        if self.config.linear_basis:
            valid = x.flatten(1).index_select(1, self.valid_index)
            mu = mu + (valid - self.basis_mean) @ self.basis_projection.T
        return mu, logvar


def clip_latent(z: torch.Tensor) -> torch.Tensor:
    """Each latent coordinate clipped to ``[−LATENT_LIMIT, LATENT_LIMIT]`` (``spec/bvae-format.md`` §6 step 2).

    Every entry point of :class:`Decoder` starts with it, so that absurd codes (``1e19``) decode the same on every
    device; within the bound it is the identity (and its gradient is 1), so training and ordinary codes are
    untouched.
    """
    return z.clamp(-LATENT_LIMIT, LATENT_LIMIT)


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
        last = self.upsample[-1]
        with torch.no_grad():
            if config.linear_basis:
                # Linear path: mean + components · z over valid entries (float16 storage); the convolutional
                # path adds a correction that starts at zero.
                n_valid = int(valid_input_index().numel())
                self.register_buffer("valid_index", valid_input_index(), persistent=False)
                self.register_buffer("basis_mean", torch.zeros(n_valid, dtype=torch.float16))
                self.register_buffer("basis_components", torch.zeros(config.latent_dim, n_valid, dtype=torch.float16))
                last.weight.zero_()
                last.bias.zero_()
            else:
                # Start near a typical mapped value (sigmoid(−2.5) · 5 ≈ 0.38), not mid-domain.
                last.bias.fill_(_INITIAL_LOGIT)

    def logits(self, z: torch.Tensor) -> torch.Tensor:
        """Output of the convolutional path, ``(B, 63, 90, 90)``."""
        c0 = self.config.decoder_channels[0]
        h = self.fc(clip_latent(z)).view(-1, c0, _BOTTLENECK, _BOTTLENECK)
        return self.upsample(self.blocks(h))

    def unbounded(self, z: torch.Tensor) -> torch.Tensor:
        """Output before it is limited to the mapped domain (the training loss uses it)."""
        z = clip_latent(z)
        out = self.logits(z)
        if not self.config.linear_basis:
            return MAPPED_MAX * torch.sigmoid(out)
        dtype = out.dtype
        linear = self.basis_mean.to(dtype) + z @ self.basis_components.to(dtype)
        flat = out.flatten(1).index_add(1, self.valid_index, linear)
        return flat.view_as(out)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        """Mapped slices in [0, MAPPED_MAX]."""
        return self.unbounded(z).clamp(0.0, MAPPED_MAX)

    def hidden_and_unbounded(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The last layer's input ``(B, C, 45, 45)`` and :meth:`unbounded` ``(B, 63, 90, 90)``, from one pass.

        For decoders that need what the output owes to each hidden activation (the projected base of
        ``spec/bvae-format.md`` §4.5 takes its dot products through the last layer's adjoint).
        """
        c0 = self.config.decoder_channels[0]
        z = clip_latent(z)
        hidden = self.upsample[:-1](self.blocks(self.fc(z).view(-1, c0, _BOTTLENECK, _BOTTLENECK)))
        out = self.upsample[-1](hidden)
        if not self.config.linear_basis:
            return hidden, MAPPED_MAX * torch.sigmoid(out)
        dtype = out.dtype
        linear = self.basis_mean.to(dtype) + z @ self.basis_components.to(dtype)
        return hidden, out.flatten(1).index_add(1, self.valid_index, linear).view_as(out)

    def forward_channels(self, z: torch.Tensor, channels: tuple[int, ...]) -> torch.Tensor:
        """Only some output channels, ``(B, len(channels), 90, 90)`` in [0, MAPPED_MAX].

        Equal to ``forward(z)[:, channels]`` up to floating-point summation
        order; the last layer and the linear path are evaluated for the chosen
        channels only (decoding one φd bin needs 6 of the 63).
        """
        c0 = self.config.decoder_channels[0]
        z = clip_latent(z)
        hidden = self.upsample[:-1](self.blocks(self.fc(z).view(-1, c0, _BOTTLENECK, _BOTTLENECK)))
        last = self.upsample[-1]
        index = list(channels)
        out = nn.functional.conv_transpose2d(
            hidden, last.weight[:, index], last.bias[index], stride=last.stride, padding=last.padding
        )
        if not self.config.linear_basis:
            return (MAPPED_MAX * torch.sigmoid(out)).clamp(0.0, MAPPED_MAX)
        select, positions = self._channel_entries(channels)
        dtype = out.dtype
        linear = self.basis_mean[select].to(dtype) + z @ self.basis_components[:, select].to(dtype)
        flat = out.flatten(1).index_add(1, positions, linear)
        return flat.view_as(out).clamp(0.0, MAPPED_MAX)

    def _channel_entries(self, channels: tuple[int, ...]) -> tuple[torch.Tensor, torch.Tensor]:
        """Which linear-basis entries fall in ``channels``, and their flat positions in the reduced output."""
        cache = self.__dict__.setdefault("_channel_cache", {})
        key = (tuple(channels), self.valid_index.device)
        if key not in cache:
            plane = NETWORK_INPUT_SHAPE[1] * NETWORK_INPUT_SHAPE[2]
            channel_of = self.valid_index // plane
            selects, positions = [], []
            for slot, channel in enumerate(channels):
                hit = (channel_of == channel).nonzero().flatten()
                selects.append(hit)
                positions.append(self.valid_index[hit] - channel * plane + slot * plane)
            cache[key] = (torch.cat(selects), torch.cat(positions))
        return cache[key]


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
        self, x: torch.Tensor, noise: torch.Tensor | None = None, offset: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Return ``(reconstruction, μ, log σ²)``.

        In training mode the reconstruction is the decoder's unbounded output
        (so the loss keeps its gradient outside the mapped domain); in
        evaluation mode it is limited to [0, MAPPED_MAX].

        Parameters
        ----------
        x : Tensor, shape (B, 63, 90, 90)
            Mapped inputs.
        noise : Tensor, shape (B, latent_dim), optional
            The ε of the reparameterisation in training mode (drawn here when
            not given; given by the trainer so that runs are reproducible
            across process counts).
        offset : Tensor, shape (B, latent_dim), optional
            Added to the sampled z in training mode (the uniform noise that
            stands in for μ's rounding on the codec's grid,
            ``TrainConfig.latent_grid``); ignored in evaluation mode.
        """
        mu, logvar = self.encoder(x)
        if self.training:
            eps = torch.randn_like(mu) if noise is None else noise
            z = mu + torch.exp(0.5 * logvar) * eps
            if offset is not None:
                z = z + offset
            return self.decoder.unbounded(z), mu, logvar
        return self.decoder(z=mu), mu, logvar


@torch.no_grad()
def initialise_linear_basis(model: BetaVAE, train_inputs: torch.Tensor) -> None:
    """Fit the linear path of a ``linear_basis`` model to training inputs (:func:`~brdfcodec.models.pca.fit_pca`
    over the entries above the horizon).

    The encoder projects onto the first ``latent_dim`` principal components
    scaled to unit variance over the training set (so μ starts whitened,
    matching the N(0, 1) prior), and the decoder maps back.
    """
    if not model.config.linear_basis:
        raise ValueError("model has no linear basis (ModelConfig.linear_basis is False)")
    k = model.config.latent_dim
    if train_inputs.shape[0] < k:
        raise ValueError(f"need at least {k} training materials to fit {k} components, got {train_inputs.shape[0]}")
    basis = fit_pca(train_inputs.detach().cpu().numpy(), k, entries=model.encoder.valid_index.cpu().numpy())
    mean = torch.from_numpy(basis.mean.astype(np.float64))
    components = torch.from_numpy(basis.components.astype(np.float64))
    scale = torch.from_numpy(basis.scale.astype(np.float64))
    model.encoder.basis_mean.copy_(mean.float())
    model.encoder.basis_projection.copy_((components / scale[:, None]).float())
    model.decoder.basis_mean.copy_(mean.half())
    model.decoder.basis_components.copy_((components * scale[:, None]).half())


def linear_path_trainable(decoder: Decoder) -> list[nn.Parameter]:
    """Make the decoder's linear path (``basis_mean``, ``basis_components``) trainable, in float32.

    The two float16 buffers become float32 parameters under the same names,
    so the state dict keeps its keys: loading it into a fresh decoder (whose
    buffers are float16, as exported) rounds them back to float16.

    Returns
    -------
    list of nn.Parameter
        The two new parameters (mean, components), for their own optimiser group.

    Raises
    ------
    ValueError
        The decoder has no linear path.
    """
    if not decoder.config.linear_basis:
        raise ValueError("the model has no linear path to train (ModelConfig.linear_basis is False)")
    made = []
    for name in ("basis_mean", "basis_components"):
        value = getattr(decoder, name)
        if isinstance(value, nn.Parameter):
            made.append(value)
            continue
        parameter = nn.Parameter(value.detach().float().clone())
        delattr(decoder, name)
        decoder.register_parameter(name, parameter)
        made.append(parameter)
    return made
