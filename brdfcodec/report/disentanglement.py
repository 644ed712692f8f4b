"""Disentanglement with known factors: MIG and DCI of a code against the factors that generated the materials.

The benchmark (issue 41, part 1; ``bvae model disentanglement``) draws
analytic materials whose factors are sampled independently
(:func:`brdfcodec.datasets.analytic.sample_factor_materials`), encodes them, and scores
the codes (the encoder's μ, or PCA coefficients) with

* **MIG**, the mutual information gap (Chen et al. 2018, "Isolating sources
  of disentanglement in VAEs"): for each factor vₖ, the gap between the two
  largest mutual informations I(zⱼ; vₖ) over the code's dimensions, divided
  by the factor's entropy H(vₖ), averaged over the factors. Codes and
  factors are discretised into bins of equal frequency (by rank,
  :func:`discretise`) rather than of equal width as in ``disentanglement_lib``,
  so that a monotone reparametrisation of a code dimension does not change
  its score; MI and entropy in nats from the joint histogram. The bin count
  is round(√(N/4)) between 2 and 20 (:func:`default_bins`): with N samples and
  B² cells the histogram's upward bias of a mutual information is about
  (B − 1)²/2N nats, which with 20 bins and a few hundred samples would hide
  the gap. 1: each factor is captured by one dimension
  alone; 0: by none, or by two equally.
* **DCI** (Eastwood & Williams 2018, "A framework for the quantitative
  evaluation of disentangled representations"): one regressor per factor
  predicts it from the code; its importance matrix R (code dimension ×
  factor) gives **disentanglement** D = Σⱼ ρⱼ (1 − H_K(Pⱼ·)) (Pⱼₖ = Rⱼₖ /
  Σₖ Rⱼₖ, entropy in base K = number of factors, ρⱼ = dimension j's share of
  all importance), **completeness** C = meanₖ (1 − H_D(P̃·ₖ)) (P̃ⱼₖ = Rⱼₖ /
  Σⱼ Rⱼₖ, base D = code size), and **informativeness** I = meanₖ of the
  held-out R² = 1 − MSE/Var of the prediction (clipped at 0; 1 is perfect).
  The regressor is gradient-boosted regression stumps (depth-1 trees, least
  squares; :func:`boosted_stumps`) written in NumPy: scikit-learn is not a
  dependency of brdfcodec. Rₖ is each code dimension's total reduction of the
  squared error over the boosting rounds (the trees' impurity importance).

Each code dimension's *dominant factor* is the factor with the largest
importance Rⱼₖ: what it moves most, the measured basis for naming it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from brdfcodec.errors import BrdfcodecError

__all__ = [
    "DisentanglementInputError",
    "DisentanglementScores",
    "StumpEnsemble",
    "benchmark_inputs",
    "boosted_stumps",
    "dci",
    "default_bins",
    "discretise",
    "format_table",
    "mig",
    "model_codes",
    "mutual_information_matrix",
    "pca_codes",
    "run_benchmark",
    "score_code",
]

#: Most bins per variable of the discretised mutual information (``disentanglement_lib``'s fixed count).
MAX_BINS = 20


def default_bins(samples: int) -> int:
    """Bins per variable for ``samples`` samples: round(√(samples / 4)), between 2 and :data:`MAX_BINS`."""
    return int(min(MAX_BINS, max(2, round((samples / 4) ** 0.5))))


class DisentanglementInputError(BrdfcodecError, ValueError):
    """Codes and factors that cannot be scored (shapes, too few samples, non-finite values)."""


def _check(codes: npt.ArrayLike, factors: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    z = np.asarray(codes, dtype=np.float64)
    v = np.asarray(factors, dtype=np.float64)
    if z.ndim != 2 or v.ndim != 2 or len(z) != len(v):
        raise DisentanglementInputError(f"codes (N, D) and factors (N, K) must have one row per sample, got shapes "
                                        f"{z.shape} and {v.shape}")
    if len(z) < 10 or z.shape[1] < 1 or v.shape[1] < 1:
        raise DisentanglementInputError(f"at least 10 samples, one code dimension and one factor are needed, got "
                                        f"codes {z.shape}, factors {v.shape}")
    if not (np.isfinite(z).all() and np.isfinite(v).all()):
        raise DisentanglementInputError("codes and factors must be finite")
    return z, v


def discretise(values: npt.ArrayLike, bins: int) -> npt.NDArray[np.int64]:
    """Equal-frequency bin indices (0 … bins − 1) of each column: ``floor(rank · bins / N)``.

    The rank of a value is the number of values below it (ties share the lowest rank, so a
    constant column is all bin 0). Bins by rank make the score invariant to a monotone
    reparametrisation of a code dimension; for a uniform factor they are its equal-width bins.

    Parameters
    ----------
    values : array_like, shape (N, M)
    bins : int

    Returns
    -------
    ndarray of int64, shape (N, M)
    """
    x = np.asarray(values, dtype=np.float64)
    if bins < 1:
        raise DisentanglementInputError(f"bins must be at least 1, got {bins}")
    out = np.empty(x.shape, dtype=np.int64)
    for column in range(x.shape[1]):
        ranks = np.searchsorted(np.sort(x[:, column]), x[:, column], side="left")
        out[:, column] = ranks * bins // len(x)
    return out


def _entropy(labels: np.ndarray) -> float:
    counts = np.bincount(labels)
    p = counts[counts > 0] / len(labels)
    return float(-(p * np.log(p)).sum())


def _mutual_information(a: np.ndarray, b: np.ndarray) -> float:
    joint = np.zeros((a.max() + 1, b.max() + 1))
    np.add.at(joint, (a, b), 1.0)
    joint /= len(a)
    pa, pb = joint.sum(axis=1, keepdims=True), joint.sum(axis=0, keepdims=True)
    nonzero = joint > 0
    return float((joint[nonzero] * np.log(joint[nonzero] / (pa @ pb)[nonzero])).sum())


def mutual_information_matrix(
    codes: npt.ArrayLike, factors: npt.ArrayLike, *, bins: int | None = None
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Discretised mutual information I(zⱼ; vₖ) and factor entropies H(vₖ), in nats
    (``bins`` per variable; :func:`default_bins` of the sample count when None).

    Returns
    -------
    mi : ndarray, shape (D, K)
    entropy : ndarray, shape (K,)
    """
    z, v = _check(codes, factors)
    bins = default_bins(len(z)) if bins is None else bins
    zb, vb = discretise(z, bins), discretise(v, bins)
    mi = np.array([[_mutual_information(zb[:, j], vb[:, k]) for k in range(v.shape[1])] for j in range(z.shape[1])])
    return mi, np.array([_entropy(vb[:, k]) for k in range(v.shape[1])])


def mig(codes: npt.ArrayLike, factors: npt.ArrayLike, *, bins: int | None = None) -> tuple[float, np.ndarray]:
    """Mutual information gap (Chen et al. 2018) and its value per factor.

    Parameters
    ----------
    codes : array_like, shape (N, D)
        One code per sample (D ≥ 2 for a gap; with D = 1 the gap is the MI itself).
    factors : array_like, shape (N, K)
        The generating factors of the samples (continuous values are binned).
    bins : int, optional
        Bins per variable; :func:`default_bins` of N by default.

    Returns
    -------
    mig : float
        Mean over factors of (largest − second largest I(zⱼ; vₖ)) / H(vₖ), in [0, 1]
        (factors of zero entropy are left out).
    per_factor : ndarray, shape (K,)
        NaN for a factor of zero entropy.
    """
    mi, entropy = mutual_information_matrix(codes, factors, bins=bins)
    ordered = np.sort(mi, axis=0)[::-1]
    second = ordered[1] if len(ordered) > 1 else np.zeros(mi.shape[1])
    with np.errstate(invalid="ignore", divide="ignore"):
        gap = np.where(entropy > 0, (ordered[0] - second) / entropy, np.nan)
    return float(np.nanmean(gap)) if np.isfinite(gap).any() else 0.0, gap


@dataclass(frozen=True)
class StumpEnsemble:
    """Gradient-boosted regression stumps: ``offset + Σ (left if x[:, feature] ≤ threshold else right)``.

    Attributes
    ----------
    offset : float
    features : ndarray of int, shape (R,)
    thresholds, left, right : ndarray of float, shape (R,)
        Each round's split and its two (learning-rate-scaled) values.
    importance : ndarray of float, shape (D,)
        Each input's total reduction of the training squared error (sum over samples).
    """

    offset: float
    features: np.ndarray
    thresholds: np.ndarray
    left: np.ndarray
    right: np.ndarray
    importance: np.ndarray

    def predict(self, x: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Predictions for inputs ``x`` of shape (N, D)."""
        data = np.asarray(x, dtype=np.float64)
        below = data[:, self.features] <= self.thresholds  # (N, R)
        return self.offset + np.where(below, self.left, self.right).sum(axis=1)


def boosted_stumps(
    x: npt.ArrayLike, y: npt.ArrayLike, *, rounds: int = 200, learning_rate: float = 0.1, candidates: int = 31
) -> StumpEnsemble:
    """Least-squares gradient boosting of depth-1 trees (stumps).

    Parameters
    ----------
    x : array_like, shape (N, D)
        Inputs (any units: splits are at quantiles).
    y : array_like, shape (N,)
        Target.
    rounds : int, default 200
        Boosting rounds (one stump each).
    learning_rate : float, default 0.1
        Shrinkage of each stump's values.
    candidates : int, default 31
        Split thresholds per input: the quantiles i / (candidates + 1).

    Returns
    -------
    StumpEnsemble
    """
    data, target = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    n, d = data.shape
    thresholds = np.quantile(data, np.arange(1, candidates + 1) / (candidates + 1), axis=0).T  # (D, T)
    left_mask = (data.T[:, None, :] <= thresholds[:, :, None]).astype(np.float64)  # (D, T, N)
    n_left = left_mask.sum(axis=2)
    n_right = n - n_left
    usable = (n_left > 0) & (n_right > 0)
    offset = float(target.mean())
    prediction = np.full(n, offset)
    importance = np.zeros(d)
    chosen: list[tuple[int, float, float, float]] = []
    for _ in range(rounds):
        residual = target - prediction
        total = residual.sum()
        s_left = left_mask @ residual  # (D, T)
        s_right = total - s_left
        with np.errstate(invalid="ignore", divide="ignore"):
            gain = np.where(usable, s_left**2 / n_left + s_right**2 / n_right - total**2 / n, -np.inf)
        j, t = np.unravel_index(int(np.argmax(gain)), gain.shape)
        if not np.isfinite(gain[j, t]) or gain[j, t] <= 0:
            break
        left_value = learning_rate * s_left[j, t] / n_left[j, t]
        right_value = learning_rate * s_right[j, t] / n_right[j, t]
        prediction += np.where(left_mask[j, t] > 0, left_value, right_value)
        before = float((residual**2).sum())
        importance[j] += before - float(((target - prediction) ** 2).sum())
        chosen.append((int(j), float(thresholds[j, t]), float(left_value), float(right_value)))
    features = np.array([c[0] for c in chosen], dtype=np.int64)
    values = np.array([c[1:] for c in chosen], dtype=np.float64).reshape(-1, 3)
    return StumpEnsemble(offset, features, values[:, 0], values[:, 1], values[:, 2], np.maximum(importance, 0.0))


def _normalised_entropy(p: np.ndarray, base: int) -> np.ndarray:
    """Entropy of each column of probabilities ``p`` in log base ``base`` (0 for base 1)."""
    if base < 2:
        return np.zeros(p.shape[1])
    with np.errstate(invalid="ignore", divide="ignore"):
        terms = np.where(p > 0, p * np.log(p), 0.0)
    return -terms.sum(axis=0) / np.log(base)


def dci(
    codes: npt.ArrayLike,
    factors: npt.ArrayLike,
    *,
    train_fraction: float = 2 / 3,
    rounds: int = 200,
    learning_rate: float = 0.1,
) -> dict[str, Any]:
    """DCI disentanglement, completeness and informativeness (Eastwood & Williams 2018).

    Parameters
    ----------
    codes : array_like, shape (N, D)
    factors : array_like, shape (N, K)
    train_fraction : float, default 2/3
        The first ``round(train_fraction · N)`` samples train the regressors; the rest measure
        informativeness (samples are already in random order when drawn independently).
    rounds, learning_rate : int, float
        Of :func:`boosted_stumps`.

    Returns
    -------
    dict
        ``disentanglement``, ``completeness``, ``informativeness`` (floats in [0, 1]),
        ``importance`` (D × K list, each factor's column normalised to sum 1; zeros where a factor's
        regressor found no split), ``r2_per_factor`` (held-out R² per factor, unclipped).
    """
    z, v = _check(codes, factors)
    n_train = int(round(train_fraction * len(z)))
    if not 5 <= n_train <= len(z) - 5:
        raise DisentanglementInputError(f"train_fraction {train_fraction} leaves fewer than 5 samples on a side")
    d, k = z.shape[1], v.shape[1]
    importance = np.zeros((d, k))
    r2 = np.zeros(k)
    for factor in range(k):
        model = boosted_stumps(z[:n_train], v[:n_train, factor], rounds=rounds, learning_rate=learning_rate)
        importance[:, factor] = model.importance
        truth = v[n_train:, factor]
        variance = float(truth.var())
        error = float(((model.predict(z[n_train:]) - truth) ** 2).mean())
        r2[factor] = 1.0 - error / variance if variance > 0 else 0.0
    column = importance.sum(axis=0)
    normalised = np.divide(importance, column, out=np.zeros_like(importance), where=column > 0)
    # Disentanglement: per code dimension, over factors, weighted by the dimension's share of the importance.
    per_dim_total = normalised.sum(axis=1)
    p_dim = np.divide(normalised.T, per_dim_total, out=np.zeros((k, d)), where=per_dim_total > 0)  # (K, D)
    disentangled = 1.0 - _normalised_entropy(p_dim, k)
    weights = per_dim_total / per_dim_total.sum() if per_dim_total.sum() > 0 else np.zeros(d)
    completeness = 1.0 - _normalised_entropy(normalised, d)
    return {
        "disentanglement": float((weights * disentangled).sum()),
        "completeness": float(completeness[column > 0].mean()) if (column > 0).any() else 0.0,
        "informativeness": float(np.clip(r2, 0.0, 1.0).mean()),
        "importance": normalised.tolist(),
        "r2_per_factor": r2.tolist(),
    }


@dataclass(frozen=True)
class DisentanglementScores:
    """MIG and DCI of one code against known factors, and each code dimension's dominant factor.

    Attributes
    ----------
    mig : float
    mig_per_factor : list of float
    disentanglement, completeness, informativeness : float
    importance : list of list of float
        D × K, each factor's column summing to 1 (:func:`dci`).
    dominant_factor : list of str
        Per code dimension, the factor of largest importance.
    dominant_share : list of float
        That factor's share of the dimension's importance (row-normalised), in [0, 1].
    dimension_weight : list of float
        Each dimension's share of all importance (ρⱼ of DCI): near 0 for a dimension no factor needs.
    r2_per_factor : list of float
        Held-out R² of each factor's regressor (unclipped; informativeness is their clipped mean).
    factor_names : list of str
    """

    mig: float
    mig_per_factor: list[float]
    disentanglement: float
    completeness: float
    informativeness: float
    importance: list[list[float]]
    dominant_factor: list[str]
    dominant_share: list[float]
    dimension_weight: list[float] = field(default_factory=list)
    r2_per_factor: list[float] = field(default_factory=list)
    factor_names: list[str] = field(default_factory=list)

    def as_row(self) -> dict[str, Any]:
        """The scores as a flat result row (``brdfcodec.report.rows``)."""
        return {
            "mig": self.mig, "mig_per_factor": self.mig_per_factor, "dci_disentanglement": self.disentanglement,
            "dci_completeness": self.completeness, "dci_informativeness": self.informativeness,
            "importance": self.importance, "dominant_factor": self.dominant_factor,
            "dominant_share": self.dominant_share, "dimension_weight": self.dimension_weight,
            "r2_per_factor": self.r2_per_factor,
            "factor_names": self.factor_names,
        }


def score_code(
    codes: npt.ArrayLike, factors: npt.ArrayLike, factor_names: Sequence[str], *, bins: int | None = None
) -> DisentanglementScores:
    """MIG, DCI and the dominant factor per code dimension (see the module docstring).

    Parameters
    ----------
    codes : array_like, shape (N, D)
    factors : array_like, shape (N, K)
    factor_names : sequence of str, length K
    bins : int, optional
        Of :func:`mig`.
    """
    z, v = _check(codes, factors)
    if len(factor_names) != v.shape[1]:
        raise DisentanglementInputError(f"{len(factor_names)} factor names for {v.shape[1]} factors")
    gap, per_factor = mig(z, v, bins=bins)
    scores = dci(z, v)
    importance = np.asarray(scores["importance"])
    rows = importance.sum(axis=1, keepdims=True)
    share = np.divide(importance, rows, out=np.zeros_like(importance), where=rows > 0)
    top = share.argmax(axis=1)
    return DisentanglementScores(
        mig=gap, mig_per_factor=[float(x) for x in per_factor],
        disentanglement=scores["disentanglement"], completeness=scores["completeness"],
        informativeness=scores["informativeness"], importance=scores["importance"],
        dominant_factor=[str(factor_names[i]) for i in top],
        dominant_share=[float(share[j, i]) for j, i in enumerate(top)],
        dimension_weight=[float(w) for w in rows[:, 0] / max(float(rows.sum()), 1e-300)],
        r2_per_factor=[float(r) for r in scores["r2_per_factor"]],
        factor_names=list(factor_names),
    )


# ---------------------------------------------------------------------------------------------- the benchmark


def _kept_relae(reference: np.ndarray, estimate: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per material: Σ|estimate − reference| / Σ|reference| over the valid kept entries (mapped domain)."""
    axes = tuple(range(1, reference.ndim))
    error = np.where(mask, np.abs(estimate - reference), 0.0).sum(axis=axes)
    return error / np.maximum(np.where(mask, np.abs(reference), 0.0).sum(axis=axes), 1e-30)


def benchmark_inputs(count: int, seed: int) -> tuple[Any, np.ndarray, np.ndarray]:
    """The benchmark's materials and their network inputs and masks, shape (count, 63, 90, 90) each.

    Parameters
    ----------
    count : int
        Materials, ≥ 10.
    seed : int
        Seed of :func:`brdfcodec.datasets.analytic.sample_factor_materials`.
    """
    from brdfcodec.datasets.analytic import sample_factor_materials

    if count < 10:
        raise DisentanglementInputError(f"the benchmark needs at least 10 materials, got {count}")
    drawn = sample_factor_materials(count, seed=seed)
    first = drawn.materials[0].kept_network_input()
    inputs = np.empty((count, *first[0].shape), dtype=np.float32)
    masks = np.empty((count, *first[1].shape), dtype=bool)
    inputs[0], masks[0] = first
    for index, material in enumerate(drawn.materials[1:], 1):
        inputs[index], masks[index] = material.kept_network_input()
    return drawn, inputs, masks


def model_codes(model: Any, inputs: np.ndarray, masks: np.ndarray, *, batch_size: int = 16) -> dict[str, Any]:
    """A model's encoder means for ``inputs`` and its base decode's error on them.

    Returns
    -------
    dict
        ``codes`` (N, D) float32 (the encoder's μ), ``relae`` (N,) mapped RelAE of the base decode
        (clamped, no layers) over the valid kept entries, ``name`` and ``decoder_sha256`` of the model.
    """
    from brdfcodec.codec import BrdfDecoder, BrdfEncoder

    encoder = BrdfEncoder(model)
    decoder = BrdfDecoder(model)
    codes, errors = [], []
    for start in range(0, len(inputs), batch_size):
        mu, _ = encoder.posterior_from_inputs(inputs[start : start + batch_size], batch_size=batch_size)
        decoded = decoder.decode_mapped(mu, batch_size=batch_size).reshape(len(mu), *inputs.shape[1:])
        codes.append(mu)
        errors.append(_kept_relae(inputs[start : start + batch_size], decoded, masks[start : start + batch_size]))
    reference = decoder.reference
    return {"codes": np.concatenate(codes), "relae": np.concatenate(errors),
            "name": reference.name if reference is not None else str(model),
            "decoder_sha256": reference.sha256 if reference is not None else None}


def pca_codes(inputs: np.ndarray, masks: np.ndarray, components: int = 8) -> dict[str, Any]:
    """PCA coefficients of ``inputs`` on their own first ``components`` principal components, and the
    reconstruction's error (clamped to the mapped domain) as for :func:`model_codes`.

    The same basis as :func:`brdfcodec.models.pca.fit_pca` of the inputs over the entries valid in every
    input (up to each component's sign), found from the N × N Gram matrix of the centred inputs (float64)
    rather than an SVD of the N × E matrix: a few hundred inputs of 387,000 entries take seconds, not minutes.
    """
    from brdfcodec.models.pca import PcaBasis
    from brdfcodec.representation import clamp_mapped

    n = len(inputs)
    if not 1 <= components < n:
        raise DisentanglementInputError(f"PCA-{components} needs more than {components} materials, got {n}")
    entries = np.flatnonzero(masks.all(axis=0))
    flat = inputs.reshape(n, -1)
    mean = np.zeros(len(entries))
    for start in range(0, len(entries), 65536):
        mean[start : start + 65536] = flat[:, entries[start : start + 65536]].mean(axis=0, dtype=np.float64)
    gram = np.zeros((n, n))
    for start in range(0, len(entries), 65536):
        block = flat[:, entries[start : start + 65536]] - mean[start : start + 65536]
        gram += block @ block.T
    eigenvalues, eigenvectors = np.linalg.eigh(gram)
    order = np.argsort(eigenvalues)[::-1][:components]
    singular = np.sqrt(np.maximum(eigenvalues[order], 1e-300))
    left = eigenvectors[:, order]  # (N, k)
    basis_rows = np.zeros((components, len(entries)))
    for start in range(0, len(entries), 65536):
        block = flat[:, entries[start : start + 65536]] - mean[start : start + 65536]
        basis_rows[:, start : start + 65536] = (left.T @ block) / singular[:, None]
    scale = np.maximum(singular / max(1, n - 1) ** 0.5, 1e-12)
    basis = PcaBasis(mean.astype(np.float32), basis_rows.astype(np.float32), scale.astype(np.float32), entries)
    codes = basis.encode(inputs)
    decoded = clamp_mapped(basis.decode(codes))
    return {"codes": codes, "relae": _kept_relae(inputs, decoded, masks), "name": f"PCA-{components}",
            "decoder_sha256": None, "basis": basis}


def aligned_pca_codes(pca: dict[str, Any], count: int) -> dict[str, Any]:
    """:func:`pca_codes`' codes turned by the rotation that aligns them with the analytic factors, as
    ``bvae model export --align-factors`` turns a model's (:func:`brdfcodec.models.alignment.factor_rotation`,
    fitted on ``count`` factor materials of :data:`~brdfcodec.models.alignment.ALIGNMENT_SEED` projected on
    the same basis). A rotation changes no reconstruction: the error is PCA's.
    """
    from brdfcodec.models.alignment import ALIGNMENT_SEED, factor_rotation

    drawn, inputs, _ = benchmark_inputs(count, ALIGNMENT_SEED)
    rotation = factor_rotation(pca["basis"].encode(inputs), drawn.factors)
    return {**pca, "codes": pca["codes"] @ rotation.T, "name": f"{pca['name']} aligned"}


def run_benchmark(
    models: Sequence[Any], *, count: int = 300, seed: int = 0, pca: bool = True, progress: Any = None
) -> list[dict[str, Any]]:
    """Score the shipped (``None``) or given models, and PCA-8, on ``count`` factor materials.

    Parameters
    ----------
    models : sequence of (str, path-like or None)
        Model folders or decoder SHA-256s; None is the shipped default model.
    count, seed : int
        Of :func:`benchmark_inputs`; materials are split 2/3 : 1/3 for DCI's regressors.
    pca : bool, default True
        Also score PCA-8 of the same materials (fitted on them), as fitted and aligned with the factors
        (:func:`aligned_pca_codes`, fitted on as many materials of another seed).
    progress : callable, optional
        Called with a short message before each step.

    Returns
    -------
    list of dict
        One result row per code (unstamped; :func:`brdfcodec.report.rows.stamp` adds the commit):
        ``code``, ``model``, ``decoder_sha256``, ``latent_dim``, ``materials``, ``seed``,
        ``base_relae_kept_mapped`` (mean), the scores of :meth:`DisentanglementScores.as_row` and ``bins``.
    """
    say = progress or (lambda message: None)
    say(f"tabulating {count} analytic materials with independent factors (seed {seed})")
    drawn, inputs, masks = benchmark_inputs(count, seed)
    sources: list[tuple[str, Any]] = [("model", model) for model in models]
    sources += [("pca", None), ("pca-aligned", None)] if pca else []
    rows = []
    fitted: dict[str, Any] = {}
    for kind, model in sources:
        say({"model": f"encoding with {model or 'the shipped default model'}", "pca": "fitting PCA-8",
             "pca-aligned": "aligning PCA-8 with the factors"}[kind])
        if kind == "model":
            result = model_codes(model, inputs, masks)
        else:
            fitted = pca_codes(inputs, masks) if kind == "pca" else aligned_pca_codes(fitted, count)
            result = fitted
        scores = score_code(result["codes"], drawn.factors, drawn.names)
        rows.append({"code": kind, "model": result["name"], "decoder_sha256": result["decoder_sha256"],
                     "latent_dim": int(result["codes"].shape[1]), "materials": count, "seed": seed,
                     "bins": default_bins(count), "base_relae_kept_mapped": float(result["relae"].mean()),
                     **scores.as_row()})
    return rows


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """A plain-text table of benchmark rows, then each code dimension's dominant factor."""
    lines = [f"{'code':<32} {'D':>2} {'MIG':>6} {'DCI-D':>6} {'DCI-C':>6} {'DCI-I':>6} {'base RelAE':>10}"]
    for row in rows:
        lines.append(f"{row['model'][:32]:<32} {row['latent_dim']:>2} {row['mig']:>6.3f} "
                     f"{row['dci_disentanglement']:>6.3f} {row['dci_completeness']:>6.3f} "
                     f"{row['dci_informativeness']:>6.3f} {row['base_relae_kept_mapped']:>10.4f}")
    lines += ["", "dominant factor per dimension (its share of the dimension's importance; the dimension's weight):"]
    for row in rows:
        parts = [f"z{j + 1} {factor} ({share:.2f}; {weight:.2f})" for j, (factor, share, weight) in
                 enumerate(zip(row["dominant_factor"], row["dominant_share"], row["dimension_weight"], strict=True))]
        lines.append(f"  {row['model']}: " + ", ".join(parts))
    return "\n".join(lines)
