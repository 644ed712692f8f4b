"""Hyper-parameters of a training run."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from typing import Any, Literal

__all__ = ["TrainConfig"]


@dataclass(frozen=True)
class TrainConfig:
    """Schedule, objective and augmentation of a β-VAE training run.

    Attributes
    ----------
    epochs : int
        Passes over the training materials (each with fresh augmentation).
    batch_size : int
        Global batch (split evenly across processes under torchrun).
    learning_rate, min_learning_rate : float
        Adam's rate after warm-up, and the end of its cosine decay.
    weight_decay : float
        Decoupled weight decay (AdamW) of the convolution and fully connected
        weights, per unit of learning rate; biases, normalisation parameters
        and the linear basis are not decayed. 0 (the default) is plain Adam.
        A weight left to decay alone shrinks by about
        ``exp(-weight_decay · Σ lr)``; over the default schedule
        Σ lr ≈ 0.5 · learning_rate · steps, so values of order 1 are needed
        for the decay to matter on ~100 materials.
    warmup_epochs : int
        Linear warm-up.
    decoder_dropout : float
        Probability that a unit of the decoder's first hidden fully connected
        layer is dropped in a training step (inverted dropout; none at
        evaluation). 0 (the default) draws no mask, so runs without it keep
        their random stream.
    traversal_weight : float
        Weight of the traversal plausibility penalty
        (:class:`brdfcodec.training.traversal.TraversalPenalty`): each step
        also decodes ``μ + t·e_d`` for every material (d uniform, t uniform in
        ``[−traversal_range, traversal_range]``) and penalises new inverted
        specular peaks, near-specular output below the floor and albedo above
        the training materials'. 0 (the default) decodes nothing more and
        draws nothing, so runs without it keep their random stream.
    traversal_range : float
        Largest traversal offset of the penalty, prior σ units (3: the span
        ``bvae model plausibility`` checks).
    traversal_hole_margin : float
        Mapped height above the floor that the penalty's ``holes`` term keeps a
        lit highlight's near-specular entries at (or the material's own value
        where lower; :class:`brdfcodec.training.traversal.TraversalPenalty`);
        0, the default, penalises only crossing the floor.
    traversal_pit_weight : float
        Weight of the penalty's ``pits`` term (a highlight that darkens towards
        its centre within θh < 4.4° more than the material does) against its
        other terms; 0, the default, leaves it out.
    traversal_directions : {"axes", "any"}
        Directions the penalty traverses: the latent axes ``e_d`` (the
        default), or unit vectors drawn uniformly on the sphere, so that
        every direction is kept plausible, also the axes of a model whose
        latent is rotated after training (``bvae model export
        --align-factors``) and the studio's moves between materials.
    linear_path_rate : float
        Learning rate of the decoder's linear path (its PCA mean and
        components, ``ModelConfig.linear_basis``) as a fraction of the
        network's. 0 (the default, v1's recipe) keeps the path frozen at its
        PCA fit; > 0 trains it in float32 (stored in float16 as before, so
        the decoder's size does not change) and needs a model with a linear
        path.
    factor_weight : float
        Weight of the factor supervision
        (:mod:`brdfcodec.training.factor_supervision`): each step also
        trains on ``factor_batch`` analytic materials of known factors and
        pulls the encoder's mean of dimension j towards factor j
        standardised (0 beyond the seventh). 0 (the default) builds no pool
        and draws nothing, so runs without it keep their random stream.
    factor_batch : int
        Analytic materials per step (global, split across processes).
    factor_materials : int
        Size of the pool of analytic factor materials the steps draw from
        (tabulated once at the start, about 0.1 s and 2.5 MB each).
    factor_seed : int
        Seed of the pool (:func:`brdfcodec.datasets.analytic.sample_factor_materials`);
        keep it apart from the disentanglement benchmark's seeds (0 by
        default) and the factor alignment's (1), so that a benchmark
        measures materials the supervision never saw.
    factor_saturation : bool
        Vary the pool's colour saturation as an eighth factor (0 grey to 1;
        without it every colour has saturation 0.7) and tie latent
        dimension 8 to it; the hue term is weighted by min(1, s / 0.7).
        Needs a latent of at least 8 dimensions.
    factor_alpha_min : float
        The pool's sharpest GGX α (its roughness factor is log-uniform
        from it to 0.6; 0.03, the benchmark's, by default): lower it so
        that sharp highlights are among the supervised materials.
    latent_grid : int
        Quantisation-aware latent: with g from 1 to 5, each training step adds
        uniform noise of width 2^−g (latent units) to the sampled z, the
        rounding that the codec's coded μ on the grid 2^−g makes
        (``spec/bvae-format.md`` §4.9), so that the decoder learns to decode
        μ so rounded. 0 (the default) adds nothing and draws nothing, so runs
        without it keep their random stream.
    mean_recon_weight : float
        Weight of a second reconstruction term, the decoder's output at μ
        itself (no sampled noise) against the input, masked and summed over
        a material's entries as the β-VAE's own, for the real batch and the
        analytic one: the codes an encoder gives (what ``bvae model
        evaluate`` decodes at effort 0, and where the codec's refinement
        starts) are then codes the decoder is trained on. 0 (the default)
        decodes nothing more, so runs without it keep their steps.
    edge_slots : bool
        Train the decoder's kept slots below the horizon that the interpolation carries into valid bins (edge
        slots, :func:`~brdfcodec.representation.edge_slots.edge_slot_targets`) towards the values that fit
        those bins best, each with its fractional weight, in both reconstruction terms: the input mask leaves
        them out, and the decoded table then runs towards an unfitted value on the horizon band (measured:
        ``reports/edge-slots/``). The encoder's input is unchanged (0 there); the
        targets follow the blend and colour permutation of their materials (a blend's at the slots that are
        edge slots of both). Needs a dataset with full tables. The analytic factor pool keeps its masks.
        False (the default) leaves the slots out, as before.
    rate_weight : float
        Weight of the latent's rate: the code length of μ on the grid
        2^−``latent_grid`` under the format's unit Laplace prior
        (:func:`brdfcodec.models.loss.latent_rate`, nats, with μ's rounding
        replaced by the same uniform noise) times ``rate_weight`` is added
        to each material's loss, so the objective becomes D + λR with the
        codec's own R. D is a sum over the ~4·10⁵ valid entries of a
        material, so λ is reconstruction error per nat: about 70 is what
        the codec's basis layer buys with a nat between 16 and 32 bytes
        (mapped RelAE 0.048 → 0.031 for 88 nats on held-out materials).
        Unlike β (scaled by M/N, far smaller), it weighs μ's bytes against
        the error. Needs ``latent_grid`` ≥ 1; 0 (the default) leaves it out.
    average_from_epoch : int
        Stochastic weight averaging: from this epoch on (counted from 1; 0,
        the default, never) the weights after every optimiser step enter an
        equal-weight running average
        (:class:`torch.optim.swa_utils.AveragedModel`), which the validation
        evaluations, ``best.pt`` and so the exported model use. Buffers (a
        frozen linear path, batch-normalisation statistics) are the live
        model's. Must not exceed ``epochs``.
    beta : float
        β of the objective (β_norm = β·M/N; 12 in the paper).
    recon : {"l2", "l1"}
        Reconstruction error summed over valid entries.
    permute_colours : float
        Probability that a material is shown with its colours permuted.
    mix_probability : float
        Probability that a material is blended (in reflectance) with another.
    seed : int
        Seeds initialisation, batching, augmentation and sampling.
    eval_every : int
        Epochs between validation evaluations (and early-stopping checks).
    patience : int
        Evaluations without improvement before stopping early; 0 disables.
    checkpoint_every : int
        Epochs between checkpoints.
    time_limit_s : float or None
        Wall-clock budget; the run checkpoints and stops when it is spent
        (``--resume`` continues it).
    folds, fold : int
        Cross-validation: with ``folds`` ≥ 2 the dataset's stored split is
        ignored; the materials are dealt into ``folds`` folds stratified by
        family (:func:`brdfcodec.datasets.split.fold_by_family`, seeded by the
        dataset's split seed), the run trains on every fold but ``fold`` and
        holds that one out. 0 (the default) uses the stored split.
    train_families : str
        Comma-separated families to train on (for example ``"merl"``); the
        materials of every other family are held out, whatever the stored
        split or fold says. Empty (the default): every family.
    all_materials : bool
        Train on every material of the dataset: the stored split is
        ignored and nothing is held out (a release model, after the recipe
        was chosen by cross-validation); ``train_families`` still applies.
        Needs ``keep="last"`` (there is nothing to choose on) and no folds.
    keep : {"best", "last"}
        Which weights ``best.pt`` (and so an export) holds: those of the
        evaluation with the lowest held-out RelAE (the default), or the last
        evaluated ones. Use ``"last"`` whenever the held-out materials are
        the test set (cross-validation, a family never seen), so that no
        choice is made on them.
    """

    epochs: int = 300
    batch_size: int = 8
    learning_rate: float = 3e-4
    min_learning_rate: float = 1e-5
    weight_decay: float = 0.0
    decoder_dropout: float = 0.0
    traversal_weight: float = 0.0
    traversal_range: float = 3.0
    traversal_directions: Literal["axes", "any"] = "axes"
    traversal_hole_margin: float = 0.0
    traversal_pit_weight: float = 0.0
    linear_path_rate: float = 0.0
    factor_weight: float = 0.0
    factor_batch: int = 8
    factor_materials: int = 256
    factor_seed: int = 100
    factor_saturation: bool = False
    factor_alpha_min: float = 0.03
    latent_grid: int = 0
    mean_recon_weight: float = 0.0
    edge_slots: bool = False
    rate_weight: float = 0.0
    average_from_epoch: int = 0
    warmup_epochs: int = 2
    beta: float = 12.0
    recon: Literal["l2", "l1"] = "l1"
    permute_colours: float = 0.5
    mix_probability: float = 0.5
    seed: int = 0
    eval_every: int = 10
    patience: int = 0
    checkpoint_every: int = 10
    time_limit_s: float | None = None
    folds: int = 0
    fold: int = 0
    train_families: str = ""
    all_materials: bool = False
    keep: Literal["best", "last"] = "best"

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.batch_size < 1:
            raise ValueError("epochs and batch_size must be ≥ 1")
        if not 0 <= self.permute_colours <= 1 or not 0 <= self.mix_probability <= 1:
            raise ValueError("permute_colours and mix_probability are probabilities in [0, 1]")
        if self.recon not in ("l2", "l1"):
            raise ValueError(f"recon must be 'l2' or 'l1', got {self.recon!r}")
        if self.learning_rate <= 0 or self.min_learning_rate < 0 or self.beta < 0:
            raise ValueError("learning rates must be positive and beta ≥ 0")
        if not 0 <= self.weight_decay < float("inf"):
            raise ValueError(f"weight_decay must be finite and ≥ 0, got {self.weight_decay}")
        if not (0 <= self.traversal_weight < float("inf") and 0 < self.traversal_range < float("inf")):
            raise ValueError(f"traversal_weight must be finite and ≥ 0 and traversal_range finite and > 0, got "
                             f"{self.traversal_weight}, {self.traversal_range}")
        if not 0 <= self.traversal_pit_weight < float("inf"):
            raise ValueError(f"traversal_pit_weight must be finite and ≥ 0, got {self.traversal_pit_weight}")
        if not 0 <= self.traversal_hole_margin < float("inf"):
            raise ValueError(f"traversal_hole_margin must be finite and ≥ 0, got {self.traversal_hole_margin}")
        if self.traversal_directions not in ("axes", "any"):
            raise ValueError(f"traversal_directions must be 'axes' or 'any', got {self.traversal_directions!r}")
        if not 0 <= self.linear_path_rate < float("inf"):
            raise ValueError(f"linear_path_rate must be finite and ≥ 0, got {self.linear_path_rate}")
        if not 0 <= self.mean_recon_weight < float("inf"):
            raise ValueError(f"mean_recon_weight must be finite and ≥ 0, got {self.mean_recon_weight}")
        if self.mean_recon_weight > 0 and self.decoder_dropout > 0:
            raise ValueError("mean_recon_weight > 0 needs decoder_dropout 0 (its decode of μ would take the "
                             "sampled codes' dropout mask)")
        if not 0 <= self.factor_weight < float("inf"):
            raise ValueError(f"factor_weight must be finite and ≥ 0, got {self.factor_weight}")
        if not 0 < self.factor_alpha_min < 0.6:
            raise ValueError(f"factor_alpha_min must be in (0, 0.6), got {self.factor_alpha_min}")
        if self.factor_batch < 1 or self.factor_materials < 1:
            raise ValueError(f"factor_batch and factor_materials must be ≥ 1, got {self.factor_batch}, "
                             f"{self.factor_materials}")
        if not (isinstance(self.latent_grid, int) and 0 <= self.latent_grid <= 5):
            raise ValueError(f"latent_grid must be an integer from 0 (none) to 5, got {self.latent_grid!r}")
        if not 0 <= self.rate_weight < float("inf"):
            raise ValueError(f"rate_weight must be finite and ≥ 0, got {self.rate_weight}")
        if self.rate_weight > 0 and self.latent_grid == 0:
            raise ValueError("rate_weight needs latent_grid ≥ 1 (the grid on which the rate is counted)")
        if not 0 <= self.average_from_epoch <= self.epochs:
            raise ValueError(f"average_from_epoch must be in [0, epochs={self.epochs}], got {self.average_from_epoch}")
        if self.folds == 1 or self.folds < 0 or not 0 <= self.fold < max(self.folds, 1):
            raise ValueError(f"folds must be 0 or at least 2 and fold in [0, folds), got {self.folds}, {self.fold}")
        if self.keep not in ("best", "last"):
            raise ValueError(f"keep must be 'best' or 'last', got {self.keep!r}")
        if self.all_materials and (self.folds or self.keep != "last"):
            raise ValueError("all_materials holds nothing out: it needs keep='last' and no folds")
        if not 0 <= self.decoder_dropout < 1:
            raise ValueError(f"decoder_dropout must be in [0, 1), got {self.decoder_dropout}")

    def to_dict(self) -> dict[str, Any]:
        """Plain dictionary (JSON-ready)."""
        return asdict(self)

    def to_json(self) -> str:
        """Canonical JSON (sorted keys)."""
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        """Inverse of :meth:`to_dict`; unknown keys are an error."""
        unknown = sorted(set(data) - {f.name for f in fields(cls)})
        if unknown:
            raise ValueError(f"unknown training config keys {unknown}")
        return cls(**data)
