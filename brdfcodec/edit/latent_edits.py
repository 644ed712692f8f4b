"""Latent edits: traversal, interpolation, per-factor mixing and green-channel grafting.

Every edit returns a record (:class:`~brdfcodec.format.bvae.LatentRecord` or
:class:`~brdfcodec.format.bvae.GraftRecord`) that can be written to a
``.bvae`` file and decoded like any other. A graft record has D + k
parameters (its code and the k grafted colour values); edits act on all of
them, so interpolating two grafted materials also interpolates their green.
A layered record (:class:`~brdfcodec.format.layered_record.LayeredRecord`) stays
layered: an edit moves its ``mu`` and keeps its basis and detail layers, so
the edited material is the edited base plus the original layers' residual
(``spec/bvae-format.md`` §4.4, "Edits"); moving ``mu`` back undoes the edit.
A basis-only record (format 2.1, no latent) cannot be edited: every edit
refuses it with :class:`~brdfcodec.errors.NoLatentError`.

Edited records carry provenance, not measurements (``spec/bvae-format.md``
§5.1): ``meta`` holds only ``edit`` (the operation and its operands, with
parameters numbered from 1 as on the command line and in the model card);
the source's RelAE and checksum are not copied, since they describe another
material. ``sigma`` follows ``mu``: copied by traversal and grafting, taken
per parameter with it by per-factor mixing, and interpolated geometrically
(so it stays > 0 for any t) by interpolation. Python arguments such as
``dim`` stay 0-based, as in NumPy.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.conventions import N_KEPT_SLICES
from brdfcodec.errors import NoLatentError
from brdfcodec.format.bvae import GraftRecord, LatentRecord, Record

__all__ = [
    "fit_graft",
    "refine_code",
    "graft",
    "interpolate",
    "mix_factors",
    "parameter_vector",
    "require_latent",
    "traverse",
    "with_parameters",
]


def require_latent(record: Record) -> None:
    """Refuse a record without a latent code (a basis-only record, format 2.1): there is nothing to edit.

    Raises
    ------
    NoLatentError
        Names the record and says how to get an editable one (``bvae compress --latent always``).
    """
    if not getattr(record, "has_latent", True):
        raise NoLatentError(record.name)


def parameter_vector(record: Record) -> np.ndarray:
    """All editable parameters: the code, then (for a graft) the grafted values.

    Raises
    ------
    NoLatentError
        The record has no latent code (:func:`require_latent`).
    """
    require_latent(record)
    if isinstance(record, GraftRecord):
        return np.concatenate([record.mu, record.graft_values])
    return record.mu.copy()


def with_parameters(
    record: Record,
    values: npt.ArrayLike,
    *,
    name: str,
    edit: dict[str, Any],
    sigma: npt.ArrayLike | None = None,
) -> Record:
    """A record like ``record`` with new parameter values (same kind and graft dims), ``meta["edit"]`` set.

    ``sigma`` (shape (latent_dim,)) defaults to the record's. A layered record
    (:class:`~brdfcodec.format.layered_record.LayeredRecord`) stays layered: only its
    ``mu`` changes and its basis and detail layers are kept as they are, so the
    edited material is the edited base plus the original layers' residual in the
    mapped domain (``spec/bvae-format.md`` §4.4, "Edits"). Its compact ``mu``
    form is kept only where the new code is stored exactly in it; otherwise ``mu``
    is stored in the file's latent dtype.
    """
    require_latent(record)
    values = np.asarray(values, dtype=np.float32)
    meta = {"edit": edit}
    d = record.latent_dim
    spread = record.sigma if sigma is None else np.asarray(sigma, dtype=np.float32)
    if isinstance(record, GraftRecord):
        return GraftRecord(name, values[:d], spread, record.graft_dims, values[d:], meta)
    from brdfcodec.format.layered_record import LayeredRecord

    if isinstance(record, LayeredRecord):
        return _layered_with_code(record, values, name=name, sigma=spread, meta=meta)
    return LatentRecord(name, values, spread, meta)


def _layered_with_code(
    record: Any, mu: np.ndarray, *, name: str, sigma: np.ndarray, meta: dict[str, Any]
) -> Record:
    """``record`` (layered) with a new ``mu``: the same layers and σ form; compact or coded μ (format 2.5) only where
    it holds ``mu`` exactly (else μ in the file's latent dtype, and a coded layer's stream without it)."""
    import dataclasses

    from brdfcodec.format.layered_record import compact_mu_values

    compact = bool(record.compact_mu)
    if compact:
        try:
            compact = bool(np.array_equal(compact_mu_values(mu, record.fixed_mu_grid), mu))
        except ValueError:  # not storable in the compact form at all
            compact = False
    coded = int(getattr(record, "coded_mu", 0))
    if coded:
        scaled = np.asarray(mu, dtype=np.float64) * float(1 << coded)
        coded = coded if bool(np.isfinite(scaled).all() and np.array_equal(np.rint(scaled), scaled)
                              and np.abs(scaled).max(initial=0.0) < 2 ** 21) else 0
    return dataclasses.replace(record, name=name, mu=mu, sigma=sigma, meta=meta, compact_mu=compact,
                               fixed_mu_grid=compact and record.fixed_mu_grid, coded_mu=coded)


def traverse(
    record: Record,
    dim: int,
    values: Sequence[float],
    *,
    unit: Literal["sigma", "absolute"] = "sigma",
    name: str | None = None,
) -> list[Record]:
    """Vary one parameter, the others fixed.

    Parameters
    ----------
    record : LatentRecord or GraftRecord
    dim : int
        Parameter index (0-based): 0 … D−1 are latent dimensions; for a graft
        record D … D+k−1 are its grafted colour values.
    values : sequence of float
        ``unit="sigma"``: offsets from the record's value in units of the
        prior's standard deviation (1 in latent units), so 0 reproduces the
        material. ``unit="absolute"``: the parameter's new values.
    name : str, optional
        Base of the new records' names (default: the record's), suffixed with
        the dimension and value.
    """
    params = parameter_vector(record)
    if not 0 <= dim < params.size:
        raise ValueError(f"dim must be in [0, {params.size}), got {dim}")
    if unit not in ("sigma", "absolute"):
        raise ValueError(f"unit must be 'sigma' or 'absolute', got {unit!r}")
    base = name or record.name
    out = []
    for value in values:
        new = params.copy()
        new[dim] = params[dim] + value if unit == "sigma" else value
        edit = {"op": "traverse", "source": record.name, "parameter": dim + 1, "value": float(value), "unit": unit}
        out.append(with_parameters(record, new, name=f"{base}.z{dim + 1}{value:+g}", edit=edit))
    return out


def _check_compatible(a: Record, b: Record) -> None:
    if a.latent_dim != b.latent_dim:
        raise ValueError(f"{a.name} and {b.name} have different latent dimensions")
    # A layered record is a latent record here: edits move its base and keep its layers (spec §4.4, "Edits");
    # interpolation and mixing keep the layers of ``a``, the material edited.
    if isinstance(a, GraftRecord) is not isinstance(b, GraftRecord) or (
        isinstance(a, GraftRecord) and a.graft_dims != b.graft_dims  # type: ignore[union-attr]
    ):
        raise ValueError(
            f"{a.name} ({a.kind}) and {b.name} ({b.kind}) are not the same kind of material; both must be plain "
            "latent records, or grafts over the same dimensions"
        )


def interpolate(a: Record, b: Record, t: float, *, name: str | None = None) -> Record:
    """Linear interpolation of all parameters: ``(1 − t)·a + t·b``; t = 0 gives a, t = 1 gives b's code exactly.

    ``a`` is the material edited: a layered ``a`` keeps its layers, so its code moves towards b's while its
    residual stays (at t = 1 the result is b's code with a's layers); b's layers are not used.
    """
    if not np.isfinite(t):
        raise ValueError(f"interpolation weight t must be finite, got {t}")
    _check_compatible(a, b)
    pa, pb = parameter_vector(a), parameter_vector(b)
    values = pa if t == 0 else pb if t == 1 else (1 - t) * pa + t * pb
    sigma = a.sigma if t == 0 else b.sigma if t == 1 else np.exp((1 - t) * np.log(a.sigma) + t * np.log(b.sigma))
    return with_parameters(a, values, name=name or f"{a.name}~{b.name}@{t:g}", sigma=sigma,
                           edit={"op": "interpolate", "a": a.name, "b": b.name, "t": float(t)})


def mix_factors(a: Record, b: Record, dims_from_a: Sequence[int], *, name: str | None = None) -> Record:
    """Per-factor interpolation (paper, Fig. 9): the chosen parameters from ``a``, all others from ``b``.

    As in :func:`interpolate`, ``a`` is the material edited: a layered ``a`` keeps its layers.
    """
    _check_compatible(a, b)
    pa, pb = parameter_vector(a), parameter_vector(b)
    chosen = sorted({int(d) for d in dims_from_a})
    if any(not 0 <= d < pa.size for d in chosen):
        raise ValueError(f"dims_from_a must lie in [0, {pa.size}), got {list(dims_from_a)}")
    values = pb.copy()
    values[chosen] = pa[chosen]
    sigma = b.sigma.copy()
    latent_chosen = [d for d in chosen if d < sigma.size]
    sigma[latent_chosen] = a.sigma[latent_chosen]
    return with_parameters(a, values, name=name or f"{a.name}+{b.name}", sigma=sigma,
                           edit={"op": "mix", "a": a.name, "b": b.name, "parameters_from_a": [d + 1 for d in chosen]})


def graft(
    record: Record, graft_values: npt.ArrayLike, colour_dims: Sequence[int], *, name: str | None = None
) -> GraftRecord:
    """Green-channel grafting (paper §5): M1 = decode(V1), M2 = decode(V2), green of M = red of M2.

    Parameters
    ----------
    record : LatentRecord
        V1 (its code is kept).
    graft_values : array_like, shape (k,)
        V2's values at ``colour_dims``; V2 equals V1 elsewhere. Passing V1's own
        values gives green = red.
    colour_dims : sequence of int
        The model's colour dimensions (``BrdfDecoder.colour_dims``).

    Notes
    -----
    A layered record's layers are not kept: a ``graft`` record has none
    (``spec/bvae-format.md`` §4.2, §4.4), so the graft is made of its base code.
    """
    if isinstance(record, GraftRecord):
        raise ValueError(f"{record.name} is already a graft; edit its parameters instead")
    require_latent(record)
    return GraftRecord(
        name or f"{record.name}.graft",
        record.mu,
        record.sigma,
        tuple(int(d) for d in colour_dims),
        np.asarray(graft_values, dtype=np.float32).reshape(-1),
        {"edit": {"op": "graft", "source": record.name}},
    )


_GRID = np.linspace(-3.0, 3.0, 7)


def _grid_start(decoder: Any, code: np.ndarray, dims: list[int], target: Any, mask: Any) -> np.ndarray:
    """Best grafted values on a 7^k grid over [−3, 3] (green-channel L1, code fixed): a global start for Adam."""
    import itertools

    import torch

    green = slice(N_KEPT_SLICES, 2 * N_KEPT_SLICES)
    red = tuple(range(N_KEPT_SLICES))
    candidates = [np.array(v, dtype=np.float32) for v in itertools.product(_GRID, repeat=len(dims))]
    candidates.append(code[dims].astype(np.float32))  # V2 = V1
    best, best_loss = candidates[-1], float("inf")
    with torch.no_grad():
        for values in candidates:
            second = code.copy()
            second[dims] = values
            z = torch.as_tensor(second)[None].to(decoder.device, decoder.dtype)
            out = decoder.network.forward_channels(z, red)[0].float().cpu()
            loss = (out - target[green]).abs()[mask[green]].mean().item()
            if loss < best_loss:
                best, best_loss = values, loss
    return best


def _fit(
    decoder: Any,
    record: LatentRecord,
    target_mapped: npt.ArrayLike,
    target_mask: npt.ArrayLike,
    graft_dims: list[int] | None,
    optimise_code: bool,
    steps: int,
    learning_rate: float,
) -> tuple[np.ndarray, np.ndarray | None, float]:
    """Adam on the mapped L1 error over valid entries; returns the best code, graft values and loss."""
    import torch

    require_latent(record)
    target = torch.as_tensor(np.asarray(target_mapped, dtype=np.float32))
    mask = torch.as_tensor(np.asarray(target_mask, dtype=bool))
    network = decoder.network
    code = torch.nn.Parameter(torch.as_tensor(record.mu.copy()))
    params = [code] if optimise_code else []
    values = None
    if graft_dims is not None:
        start = _grid_start(decoder, record.mu, graft_dims, target, mask)
        values = torch.nn.Parameter(torch.as_tensor(start))
        params.append(values)
    optimiser = torch.optim.Adam(params, lr=learning_rate)
    red = tuple(range(N_KEPT_SLICES))
    green = slice(N_KEPT_SLICES, 2 * N_KEPT_SLICES)
    best: tuple[float, np.ndarray, np.ndarray | None] = (float("inf"), record.mu.copy(), None)

    def to_device(z: torch.Tensor) -> torch.Tensor:
        return z[None].to(decoder.device, decoder.dtype)

    for _ in range(steps):
        if graft_dims is None:
            output = network.unbounded(to_device(code))[0].float().cpu()
            loss = (output - target).abs()[mask].mean()
        else:
            second = code.detach().clone() if not optimise_code else code.clone()
            second = torch.index_put(second, (torch.tensor(graft_dims),), values)
            grafted_green = network.forward_channels(to_device(second), red)[0].float().cpu()
            if optimise_code:
                own = network.unbounded(to_device(code))[0].float().cpu()
                output = torch.cat([own[:N_KEPT_SLICES], grafted_green, own[2 * N_KEPT_SLICES :]])
                loss = (output - target).abs()[mask].mean()
            else:
                loss = (grafted_green - target[green]).abs()[mask[green]].mean()
        if loss.item() < best[0]:
            best = (
                loss.item(),
                code.detach().numpy().copy(),
                None if values is None else values.detach().numpy().copy(),
            )
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    return best[1], best[2], best[0]


def refine_code(
    decoder: Any,
    record: LatentRecord,
    target_mapped: npt.ArrayLike,
    target_mask: npt.ArrayLike,
    *,
    steps: int = 150,
    learning_rate: float = 0.05,
) -> LatentRecord:
    """Optimise the 8 latent values (no graft) to fit a target: the network's best without extra parameters.

    Parameters are as for :func:`fit_graft`.
    """
    code, _, loss = _fit(decoder, record, target_mapped, target_mask, None, True, steps, learning_rate)
    return LatentRecord(record.name, code, record.sigma,
                        {"edit": {"op": "refine", "source": record.name, "l1_mapped": loss}})


def fit_graft(
    decoder: Any,
    record: LatentRecord,
    target_mapped: npt.ArrayLike,
    target_mask: npt.ArrayLike,
    *,
    colour_dims: Sequence[int] | None = None,
    optimise_code: bool = True,
    steps: int = 150,
    learning_rate: float = 0.05,
) -> GraftRecord:
    """Tune the 10 parameters of a grafted material to fit a target (paper §5, Fig. 8).

    The green channel of the graft is the red channel of decode(V2), where V2
    equals V1 except at the colour dimensions. Adam minimises the L1 error in
    the mapped domain over the valid entries of the target's network input,
    starting from V1 = the record's code and V2 = V1.

    Parameters
    ----------
    decoder : brdfcodec.codec.BrdfDecoder
    record : LatentRecord
        Starting code, usually the encoder's code for the target.
    target_mapped, target_mask : array_like, shape (63, 90, 90)
        The target's network input and validity mask
        (:func:`brdfcodec.representation.network_input_from_table`).
    colour_dims : sequence of int, optional
        Default: the decoder's colour dimensions.
    optimise_code : bool, default True
        Tune V1's 8 values too (10 parameters in all); with False only the
        k grafted values move and only the green channel is fitted.
    steps, learning_rate : int, float
        Adam iterations and step size (latent units).

    Returns
    -------
    GraftRecord
        Named ``NAME.graft`` after the record, as :func:`graft` names its result.
    """
    dims = [int(d) for d in (decoder.colour_dims if colour_dims is None else colour_dims)]
    code, values, loss = _fit(decoder, record, target_mapped, target_mask, dims, optimise_code, steps, learning_rate)
    if values is None:  # _fit returns graft values whenever it is given graft dimensions
        raise RuntimeError("graft fitting returned no grafted values")
    meta = {"edit": {"op": "fit-graft", "source": record.name, "l1_mapped": loss}}
    return GraftRecord(f"{record.name}.graft", code, record.sigma, tuple(dims), values, meta)
