"""The records a ``.bvae`` file holds: a material's latent code, and a grafted pair (``spec/bvae-format.md`` §4).

:class:`LatentRecord` (§4.1) and :class:`GraftRecord` (§4.2) are plain values
checked at construction; the layered record (§4.4) builds on
:class:`LatentRecord` in :mod:`brdfcodec.format.layered_record`. Reading and writing
them is :mod:`brdfcodec.format.bvae`'s job; this module knows no bytes.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Final, Literal

import numpy as np
import numpy.typing as npt

from brdfcodec.format.material_names import check_material_name

__all__ = ["MAX_LATENT_DIM", "GraftRecord", "LatentRecord", "meta_problem"]

#: Longest latent code a record may hold.
MAX_LATENT_DIM: Final = 1024
SHA256_HEX = re.compile(r"^[0-9a-f]{64}$")


def _as_latent(values: npt.ArrayLike, label: str) -> np.ndarray:
    array = np.array(values, dtype=np.float32).reshape(-1)
    array.setflags(write=False)
    if not np.isfinite(array).all():
        raise ValueError(f"{label} must be finite, got {array}")
    return array


def _check_name(name: object) -> str:
    return check_material_name(name)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def meta_problem(meta: Mapping[str, Any]) -> str | None:
    """Why a record's ``meta`` breaks the types of §5, or None (other keys are free JSON)."""
    for key in ("source_sha256", "encoder_sha256"):
        if key in meta and not (isinstance(meta[key], str) and SHA256_HEX.match(meta[key])):
            return f"meta field {key!r} must be 64 lower-case hex digits, got {meta[key]!r}"
    if "relae" in meta:
        relae = meta["relae"]
        if not isinstance(relae, Mapping):
            return f"meta field 'relae' must be an object, got {type(relae).__name__}"
        for part in ("mapped", "linear"):
            if part in relae and not (_is_number(relae[part]) and math.isfinite(relae[part]) and relae[part] >= 0):
                return f"meta field 'relae.{part}' must be a finite number >= 0, got {relae[part]!r}"
    if "edit" in meta:
        edit = meta["edit"]
        if not isinstance(edit, Mapping) or not isinstance(edit.get("op"), str):
            return "meta field 'edit' must be an object with a string 'op'"
    if "source_kind" in meta and not isinstance(meta["source_kind"], str):
        return f"meta field 'source_kind' must be a string, got {meta['source_kind']!r}"
    if "effort" in meta:
        effort = meta["effort"]
        if not (isinstance(effort, int) and not isinstance(effort, bool) and 0 <= effort <= 3):
            return f"meta field 'effort' must be an integer in [0, 3], got {effort!r}"
    if "rate" in meta and not isinstance(meta["rate"], Mapping):
        return f"meta field 'rate' must be an object, got {type(meta['rate']).__name__}"
    return None


@dataclass(frozen=True)
class LatentRecord:
    """One material as the encoder's posterior ``N(mu, diag(sigma²))``.

    Attributes
    ----------
    name : str
        Material name, unique in its file.
    mu, sigma : ndarray of float32, shape (latent_dim,)
        Posterior mean (the code that is decoded) and standard deviation (> 0),
        in latent units (the prior is N(0, 1)).
    meta : dict
        Optional facts (``spec/bvae-format.md`` §5): ``source_sha256``,
        ``relae`` (``{"mapped": float, "linear": float}``), ``encoder_sha256``,
        ``source_kind`` (str), ``effort`` (int, 0–3), ``rate`` (object),
        ``edit`` (how an edited material was made), and any other JSON value.
    """

    name: str
    mu: np.ndarray
    sigma: np.ndarray
    meta: Mapping[str, Any] = field(default_factory=dict)

    kind: Literal["latent"] = field(default="latent", init=False)

    def __post_init__(self) -> None:
        _check_name(self.name)
        object.__setattr__(self, "mu", _as_latent(self.mu, "mu"))
        object.__setattr__(self, "sigma", _as_latent(self.sigma, "sigma"))
        if self.mu.shape != self.sigma.shape:
            raise ValueError(f"mu and sigma differ in length: {self.mu.shape} and {self.sigma.shape}")
        if not 1 <= self.mu.size <= MAX_LATENT_DIM:
            raise ValueError(f"latent dimension must be 1 to {MAX_LATENT_DIM}, got {self.mu.size}")
        if not (self.sigma > 0).all():
            raise ValueError(f"sigma must be > 0, got {self.sigma}")
        if not isinstance(self.meta, Mapping):
            raise ValueError(f"meta must be a mapping, got {type(self.meta).__name__}")
        problem = meta_problem(self.meta)
        if problem is not None:
            raise ValueError(f"{self.name}: {problem}")
        object.__setattr__(self, "meta", dict(self.meta))

    @property
    def latent_dim(self) -> int:
        """Length of the latent code."""
        return int(self.mu.size)

    def payload_values(self) -> np.ndarray:
        """Values in payload order: ``mu`` then ``sigma``."""
        return np.concatenate([self.mu, self.sigma])


@dataclass(frozen=True)
class GraftRecord:
    """A composite material made by green-channel grafting (paper §5; spec §4.2).

    The material decodes ``mu`` (M1) and a second code equal to ``mu`` except
    at ``graft_dims``, where it takes ``graft_values`` (M2); its table is M1
    with M1's green channel replaced by M2's red channel.

    Attributes
    ----------
    name, mu, sigma, meta
        As in :class:`LatentRecord` (``mu``/``sigma`` are V1's).
    graft_dims : tuple of int
        Latent dimensions that control colour (the model's colour dimensions).
    graft_values : ndarray of float32, shape (len(graft_dims),)
        V2's values at those dimensions: the extra parameters.
    """

    name: str
    mu: np.ndarray
    sigma: np.ndarray
    graft_dims: tuple[int, ...]
    graft_values: np.ndarray
    meta: Mapping[str, Any] = field(default_factory=dict)

    kind: Literal["graft"] = field(default="graft", init=False)

    def __post_init__(self) -> None:
        LatentRecord.__post_init__(self)  # type: ignore[arg-type]  # same checks on the shared fields
        dims = tuple(int(d) for d in self.graft_dims)
        if not dims or len(set(dims)) != len(dims) or not all(0 <= d < self.mu.size for d in dims):
            raise ValueError(f"graft_dims must be distinct latent indices in [0, {self.mu.size}), got {dims}")
        object.__setattr__(self, "graft_dims", dims)
        object.__setattr__(self, "graft_values", _as_latent(self.graft_values, "graft_values"))
        if self.graft_values.size != len(dims):
            raise ValueError(f"need one graft value per graft dimension, got {self.graft_values.size} for {dims}")

    @property
    def latent_dim(self) -> int:
        """Length of the latent code."""
        return int(self.mu.size)

    def second_code(self) -> np.ndarray:
        """V2: ``mu`` with ``graft_values`` at ``graft_dims``."""
        v2 = self.mu.copy()
        v2[list(self.graft_dims)] = self.graft_values
        return v2

    def payload_values(self) -> np.ndarray:
        """Values in payload order: ``mu``, ``sigma``, ``graft_values``."""
        return np.concatenate([self.mu, self.sigma, self.graft_values])
