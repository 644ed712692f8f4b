"""Encode-time refinement of the latent against the decoder (closing the amortisation gap), and the fit of the
basis coefficients of a record without a latent (format 2.1).

The encoder's μ is a fast guess. Refinement starts from it and takes a few
Adam steps on the mapped-domain L1 error of the decoded kept slices over the
valid entries — the numerator of the mapped RelAE — and keeps the best code
seen (never worse than μ on the material). L1 was chosen over L2 because,
on materials the encoder was not trained on, refinement lowers the mapped
RelAE more with it (documentation: Layers and rate control).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

import numpy as np
import numpy.typing as npt
import torch

from brdfcodec.codec.basis_operator import BasisOperator

__all__ = [
    "BASIS_ONLY_STEPS",
    "BASIS_STEPS",
    "EFFORT_STEPS",
    "LAYER_POLISH_PASSES",
    "POLISH_PASSES",
    "fit_basis_coefficients",
    "fit_basis_only_coefficients",
    "polish_quantised_coefficients",
    "refine_latent",
]

#: Adam steps per effort level (0 = the encoder's μ as is).
EFFORT_STEPS: Final = {0: 0, 1: 4, 2: 20, 3: 60}
#: Adam learning rate in latent units (the prior is N(0, 1)).
LEARNING_RATE: Final = 0.05


def refine_latent(
    decoder: torch.nn.Module,
    mu: npt.ArrayLike,
    inputs: npt.ArrayLike,
    masks: npt.ArrayLike,
    effort: int,
) -> npt.NDArray[np.float32]:
    """Refined latent codes of a batch of materials.

    Parameters
    ----------
    decoder : torch.nn.Module
        The model's decoder (latent → mapped kept slices ``(B, 63, 90, 90)``).
    mu : array_like, shape (B, latent_dim)
        Encoder means (the starting point).
    inputs : array_like, shape (B, 63, 90, 90)
        Mapped kept slices of the materials.
    masks : array_like of bool, shape (B, 63, 90, 90)
        Valid entries (above the horizon).
    effort : int
        0 to 3 (see :data:`EFFORT_STEPS`).

    Returns
    -------
    ndarray of float32, shape (B, latent_dim)
        For each material the code with the lowest L1 error among μ and the
        iterates (μ itself when ``effort`` is 0).
    """
    if effort not in EFFORT_STEPS:
        raise ValueError(f"effort must be one of {sorted(EFFORT_STEPS)}, got {effort!r}")
    start = np.array(mu, dtype=np.float32, ndmin=2)
    steps = EFFORT_STEPS[effort]
    if steps == 0:
        return start
    parameter = next(decoder.parameters())
    device, dtype = parameter.device, parameter.dtype
    target = torch.as_tensor(np.asarray(inputs, dtype=np.float32), device=device, dtype=dtype)
    weight = torch.as_tensor(np.asarray(masks, dtype=np.float32), device=device, dtype=dtype)
    z = torch.tensor(start, device=device, dtype=dtype, requires_grad=True)
    adam = _Adam(z, LEARNING_RATE)
    best = z.detach().clone()
    best_error = torch.full((len(start),), float("inf"), device=device)
    grads = [p.requires_grad for p in decoder.parameters()]
    for p in decoder.parameters():
        p.requires_grad_(False)
    try:
        with torch.enable_grad():
            for step in range(steps + 1):
                error = ((decoder(z) - target) * weight).abs().flatten(1).sum(1)
                better = error.detach() < best_error
                best[better] = z.detach()[better]
                best_error = torch.minimum(best_error, error.detach())
                if step == steps:
                    break
                z.grad = None
                error.sum().backward()
                adam.step()
    finally:
        for p, g in zip(decoder.parameters(), grads, strict=True):
            p.requires_grad_(g)
    out = best.float().cpu().numpy()
    return out if np.isfinite(out).all() else start


class _Adam:
    """Adam (Kingma and Ba 2015) on one tensor, with ``torch.optim.Adam``'s defaults and update formula.

    Written out because ``torch.optim.Adam``'s first ``step`` imports
    ``torch._dynamo``, which took longer than the whole default-effort
    refinement of a material, and was paid by every ``bvae compress`` process. The update is
    the same as ``torch.optim.Adam(lr=lr)`` (betas 0.9, 0.999, eps 1e-8, no
    weight decay): ``tests/test_layers.py`` checks it against torch's.
    """

    def __init__(self, parameter: torch.Tensor, lr: float, betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-8) -> None:
        self.parameter, self.lr, self.betas, self.eps = parameter, lr, betas, eps
        self.exp_avg = torch.zeros_like(parameter)
        self.exp_avg_sq = torch.zeros_like(parameter)
        self.steps = 0

    @torch.no_grad()
    def step(self) -> None:
        """One update from ``parameter.grad``."""
        grad = self.parameter.grad
        if grad is None:
            return
        beta1, beta2 = self.betas
        self.steps += 1
        self.exp_avg.lerp_(grad, 1 - beta1)
        self.exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
        bias_correction1 = 1 - beta1**self.steps
        bias_correction2_sqrt = (1 - beta2**self.steps) ** 0.5
        denom = (self.exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(self.eps)
        self.parameter.addcdiv_(self.exp_avg, denom, value=-self.lr / bias_correction1)


#: Adam steps of the joint fit of the latent and the basis coefficients, per effort level (0: least squares only).
BASIS_STEPS: Final = {0: 0, 1: 20, 2: 60, 3: 150}
#: Adam learning rate of the basis coefficients (mapped units; the basis vectors have unit norm).
BASIS_LEARNING_RATE: Final = 0.05
#: Adam learning rate of the latent during the joint fit (smaller than alone: the coefficients follow it).
JOINT_LATENT_RATE: Final = 0.02


def _mapped_l1(decoded: torch.Tensor, target: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    return ((decoded - target) * weight).abs().sum(1)


def fit_basis_coefficients(
    decoder: torch.nn.Module,
    codes: npt.ArrayLike,
    inputs: npt.ArrayLike,
    masks: npt.ArrayLike,
    components: npt.ArrayLike | BasisOperator,
    entries: npt.ArrayLike,
    effort: int,
    *,
    fit_latent: bool = True,
    error: Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor] | None = None,
    projection: tuple[npt.ArrayLike | BasisOperator, npt.ArrayLike] | None = None,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Latent codes and basis coefficients fitted together (the basis layer's encoder).

    Starts from ``codes`` and the least-squares coefficients of the residual
    they leave (the orthogonal projection of ``x − clamp(D(z))`` on the basis,
    over valid entries), then takes :data:`BASIS_STEPS` ``[effort]`` Adam steps
    on the mapped L1 error of ``clamp(D(z)) + Σ cᵢ bᵢ`` over valid entries, and
    keeps, per material, the best pair seen (the start with no coefficients included).

    Parameters
    ----------
    decoder : torch.nn.Module
        Latent → mapped kept slices ``(B, 63, 90, 90)``.
    codes : array_like, shape (B, latent_dim)
        Starting codes (refined μ).
    inputs, masks : array_like, shape (B, 63, 90, 90)
        Mapped kept slices and validity.
    components : array_like, shape (k, E), or BasisOperator
        The k vectors of the shared basis the coefficients weigh (a :class:`BasisOperator` sums on a
        factorised basis' factors).
    entries : array_like of int, shape (E,)
        Their flat positions in the ``(63, 90, 90)`` layout.
    effort : int
        0 to 3.
    fit_latent : bool, default True
        False keeps ``codes`` as they are and fits the coefficients alone (for a code already quantised as
        it will be stored: the decoder then runs once).
    error : callable, optional
        ``error(decoded, target, weight)`` → per-material error ``(B,)`` to minimise, all three ``(B, 63·90·90)``
        tensors (mapped kept slices; validity as 0/1); the mapped L1 error over valid entries by default.
        For trying other objectives; the encoder uses the default.
    projection : (vectors, centre), optional
        Project the clamped base decode at ``entries`` on ``vectors`` ``(P, E)`` or an operator of them (the
        shared basis' first P)
        around ``centre`` ``(E,)`` before the coefficients are added: a projected base (format 1.6,
        :meth:`~brdfcodec.layers.basis.SharedBasis.project`).

    Returns
    -------
    codes : ndarray of float32, shape (B, latent_dim)
    coefficients : ndarray of float32, shape (B, k)
    """
    from brdfcodec.conventions import MAPPED_MAX

    if effort not in BASIS_STEPS:
        raise ValueError(f"effort must be one of {sorted(BASIS_STEPS)}, got {effort!r}")
    error = _mapped_l1 if error is None else error
    parameter = next(decoder.parameters())
    device, dtype = parameter.device, parameter.dtype
    start = torch.as_tensor(np.array(codes, dtype=np.float32, ndmin=2), device=device, dtype=dtype)
    target = torch.as_tensor(np.asarray(inputs, dtype=np.float32), device=device, dtype=dtype).flatten(1)
    weight = torch.as_tensor(np.asarray(masks, dtype=np.float32), device=device, dtype=dtype).flatten(1)
    basis = _as_operator(components)
    where = torch.as_tensor(np.asarray(entries, dtype=np.int64), device=device)
    grads = [p.requires_grad for p in decoder.parameters()]
    for p in decoder.parameters():
        p.requires_grad_(False)

    fixed_base: torch.Tensor | None = None
    if projection is not None:
        p_vectors = _as_operator(projection[0])
        p_centre = torch.as_tensor(np.array(projection[1], dtype=np.float32), device=device, dtype=dtype)

    def base_of(z: torch.Tensor) -> torch.Tensor:
        base = decoder(z).clamp(0.0, MAPPED_MAX).flatten(1)
        if projection is None:
            return base
        centred = base[:, where] - p_centre
        return base.index_copy(1, where, p_centre + p_vectors.synthesise(p_vectors.analyse(centred)))

    def decoded(z: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        base = base_of(z) if fixed_base is None else fixed_base
        return base.index_add(1, where, basis.synthesise(c))

    try:
        with torch.no_grad():
            start_base = base_of(start)
            if not fit_latent:
                fixed_base = start_base
            residual = (target - start_base) * weight
            c0 = basis.analyse(residual[:, where])
            # No coefficients at all is a candidate too: on a material unlike the training ones the projection
            # (best in L2) can raise the L1 error.
            best_error = error(decoded(start, torch.zeros_like(c0)), target, weight)
        z = start.clone().requires_grad_(True)
        c = c0.clone().requires_grad_(True)
        best_z, best_c = start.clone(), torch.zeros_like(c0)
        steps = BASIS_STEPS[effort]
        adam_z, adam_c = _Adam(z, JOINT_LATENT_RATE), _Adam(c, BASIS_LEARNING_RATE)
        with torch.enable_grad():
            for step in range(steps + 1):
                current = error(decoded(z, c), target, weight)
                better = current.detach() < best_error
                best_z[better], best_c[better] = z.detach()[better], c.detach()[better]
                best_error = torch.minimum(best_error, current.detach())
                if step == steps:
                    break
                z.grad = c.grad = None
                current.sum().backward()
                if fit_latent:
                    adam_z.step()
                adam_c.step()
    finally:
        for p, g in zip(decoder.parameters(), grads, strict=True):
            p.requires_grad_(g)
    out_z, out_c = best_z.float().cpu().numpy(), best_c.float().cpu().numpy()
    if not (np.isfinite(out_z).all() and np.isfinite(out_c).all()):
        return start.float().cpu().numpy(), c0.float().cpu().numpy()
    return out_z, out_c


#: Adam steps of the coefficients of a record without a latent (format 2.1), per effort level (0: least squares
#: only). Only the coefficients move, and each step is one pass over k basis vectors (no network), so they are
#: cheaper than the joint fit's and more of them fit in the same time.
BASIS_ONLY_STEPS: Final = {0: 0, 1: 40, 2: 100, 3: 250}
#: Adam learning rate of those coefficients (mapped units): larger than the joint fit's, which starts from a fitted
#: latent; here the least-squares start is all there is.
BASIS_ONLY_RATE: Final = 0.2
#: Passes of the integer polish of a quantised basis layer without a latent, per effort level.
POLISH_PASSES: Final = {0: 0, 1: 2, 2: 4, 3: 8}
#: Passes of the integer polish of a packed or coded basis layer beside a latent (on the base as decoded), per
#: effort level: a pass costs no network evaluation, and a sweep that moves nothing ends the polish early.
LAYER_POLISH_PASSES: Final = {0: 0, 1: 4, 2: 8, 3: 16}


def fit_basis_only_coefficients(
    inputs: npt.ArrayLike,
    masks: npt.ArrayLike,
    centre: npt.ArrayLike,
    components: npt.ArrayLike | BasisOperator,
    effort: int,
) -> npt.NDArray[np.float32]:
    """Basis coefficients of a record without a latent (format 2.1): its decode is clamp(m + Σ cᵢ vᵢ).

    Starts from the least-squares coefficients of ``x − m`` over the valid entries (the projection of the
    masked residual on the vectors), then takes :data:`BASIS_ONLY_STEPS` ``[effort]`` Adam steps on the mapped
    L1 error of the clamped sum over the valid entries, and keeps the best coefficients seen (the start
    included): the joint fit of :func:`fit_basis_coefficients` with no latent.

    Parameters
    ----------
    inputs, masks : array_like, shape (E,)
        The material's mapped kept slices and their validity at the basis' entries.
    centre : array_like, shape (E,)
        m: the decoder's linear-path mean at those entries.
    components : array_like, shape (k, E), or BasisOperator
        The basis vectors ``0 … k − 1``.
    effort : int
        0 to 3.

    Returns
    -------
    ndarray of float32, shape (k,)
    """
    from brdfcodec.conventions import MAPPED_MAX

    if effort not in BASIS_ONLY_STEPS:
        raise ValueError(f"effort must be one of {sorted(BASIS_ONLY_STEPS)}, got {effort!r}")
    target = torch.as_tensor(np.asarray(inputs, dtype=np.float32).reshape(-1))
    weight = torch.as_tensor(np.asarray(masks, dtype=np.float32).reshape(-1))
    mean = torch.as_tensor(np.asarray(centre, dtype=np.float32).reshape(-1))
    basis = _as_operator(components)

    def error(c: torch.Tensor) -> torch.Tensor:
        return ((torch.clamp(mean + basis.synthesise(c[None])[0], 0.0, MAPPED_MAX) - target) * weight).abs().sum()

    with torch.no_grad():
        start = basis.analyse(((target - mean) * weight)[None])[0]
        best, best_error = start.clone(), error(start)
    steps = BASIS_ONLY_STEPS[effort]
    if steps:
        c = start.clone().requires_grad_(True)
        adam = _Adam(c, BASIS_ONLY_RATE)
        with torch.enable_grad():
            for step in range(steps + 1):
                current = error(c)
                if current.detach() < best_error:
                    best, best_error = c.detach().clone(), current.detach()
                if step == steps:
                    break
                c.grad = None
                current.backward()
                adam.step()
    out = best.numpy().astype(np.float32)
    return out if np.isfinite(out).all() else start.numpy().astype(np.float32)


def polish_quantised_coefficients(
    step: float,
    q: npt.ArrayLike,
    inputs: npt.ArrayLike,
    masks: npt.ArrayLike,
    centre: npt.ArrayLike,
    components: npt.ArrayLike | BasisOperator,
    passes: int,
    bounds: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
    fits: Callable[[npt.NDArray[np.int64]], bool] | None = None,
) -> npt.NDArray[np.int8] | npt.NDArray[np.int64]:
    """Integer coefficients moved a step at a time while that lowers the mapped L1 error of clamp(m + s·Σ qᵢ vᵢ).

    Rounding each coefficient to the step s = max |c| / 127 adds an error the float fit never saw; this
    coordinate descent (each qᵢ tried one step up and down, a move kept while it lowers the error; at most
    ``passes`` sweeps, fewer when a sweep moves nothing) takes some of it back. The step is kept, so the
    layer's bytes keep their meaning; values stay within −127 … 127 as the writer's.

    Parameters
    ----------
    step : float
        s (the layer's float16 step).
    q : array_like of int, shape (k,)
        The rounded coefficients.
    inputs, masks, centre : array_like, shape (E,)
        As for :func:`fit_basis_only_coefficients`.
    components : array_like, shape (k, E), or BasisOperator
    passes : int
    bounds : (low, high) of array_like of int, shape (k,), optional
        Each integer's range (a packed layer's fields, :mod:`brdfcodec.layers.packed`); default −127 … 127.
    fits : callable, optional
        ``fits(integers)`` → whether the layer of these integers still fits its bytes (an entropy-coded layer,
        whose size depends on its values): a move that lowers the error is kept only where it does.

    Returns
    -------
    ndarray of int8 (int64 with ``bounds``), shape (k,)
    """
    from brdfcodec.conventions import MAPPED_MAX

    codes = np.asarray(q, dtype=np.int64).copy()
    low, high = (np.full(len(codes), -127), np.full(len(codes), 127)) if bounds is None else (
        np.asarray(bounds[0], dtype=np.int64), np.asarray(bounds[1], dtype=np.int64))
    vectors = _as_operator(components)
    x = np.asarray(inputs, dtype=np.float32).reshape(-1)
    w = np.asarray(masks, dtype=np.float32).reshape(-1)
    scratch = np.empty_like(x)

    def error(values: np.ndarray) -> float:
        np.clip(values, 0.0, MAPPED_MAX, out=scratch)
        np.subtract(scratch, x, out=scratch)
        np.abs(scratch, out=scratch)
        return float(np.dot(scratch, w))

    mean = np.asarray(centre, dtype=np.float32).reshape(-1)
    decoded = mean + vectors.combine(np.float32(step) * codes.astype(np.float32))
    current = error(decoded)
    for _ in range(passes):
        moved = False
        for i in range(len(codes)):
            vector = vectors.row(i)
            for direction in (1, -1):
                change = np.float32(direction * step) * vector
                steps = 0
                while low[i] <= codes[i] + direction <= high[i]:  # further while each step lowers the error
                    trial = decoded + change
                    trial_error = error(trial)
                    if trial_error >= current:
                        break
                    if fits is not None:
                        codes[i] += direction
                        fitting = fits(codes)
                        codes[i] -= direction
                        if not fitting:
                            break
                    decoded, current, codes[i], steps = trial, trial_error, codes[i] + direction, steps + 1
                if steps:  # moved up: no need to try down
                    moved = True
                    break
        if not moved:
            break
    return codes.astype(np.int8) if bounds is None else codes


def _as_operator(components: npt.ArrayLike | BasisOperator) -> BasisOperator:
    return components if isinstance(components, BasisOperator) else BasisOperator.from_vectors(components)
