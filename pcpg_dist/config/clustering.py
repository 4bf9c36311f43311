"""Config of Step A (section ``clustering``): the method (one of the table in
:mod:`pcpg_dist.config.clusterers`) and the settings of its fit."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from pcpg_dist.config.clusterers import ClusterMethod
from pcpg_dist.config.schema import StrictModel


class ClusterConfig(StrictModel):
    """Step A settings. The default method, bag_auto (greedy_mix on discrete states), is the best
    label-free clusterer on 20 held-out random GridWorld layouts and falls back to policy_mix on
    continuous states (chosen on the zoo's design games, docs/zoo.md; lstm_dec where a log's
    actions say nothing); the paper's lstm_dec stays available by name."""

    method: ClusterMethod = Field(
        "bag_auto",
        description="lstm_dec: autoencoder + DEC loss (the paper); lstm_kmeans: k-means on "
        "pretrained latents; summary_kmeans: k-means on length, final and mean state; "
        "visits_kmeans: k-means (cosine) on which distinct states a trajectory visits (for "
        "discrete-state games; no network, seconds); bag_kmeans: weighted k-means (cosine) on "
        "distinct rows of visited states + state-actions + final state; bag_mop: a mixture of k "
        "policies (EM) started from bag_kmeans; greedy_mix: a mixture of k greedy policies with one "
        "uniform noise level, refined from bag_kmeans (discrete states); bag_auto: greedy_mix, "
        "or policy_mix where states are continuous (lstm_dec where one action is logged throughout); "
        "policy_mix: a mixture of k neural policies (hard EM) started from k-means on the "
        "monotone features' gain and mean, for continuous states; choice_mix: a mixture of k "
        "choice models over what each legal move does (clustering.move_features; bag_auto uses "
        "it whenever that is set) (docs/clustering.md).",
    )
    move_features: str | None = Field(
        None,
        pattern=r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$",
        description="'package.module:function' of your own: function(state, legal_ids) -> "
        "(len(legal_ids), F) numbers saying what each legal move does (a capture, a check, ...), "
        "for games whose move ids do not say it; clusters with choice_mix "
        "(docs/clustering.md, 'What a move does').",
    )
    k: int = Field(4, ge=1, le=1000, description="Number of clusters (play-styles).")
    hidden_size: int = Field(
        32, ge=1, le=1024, description="LSTM hidden units of encoder and decoder."
    )
    latent_size: int = Field(8, ge=1, le=512, description="Size of the latent trajectory code z.")
    pooling: Literal["last", "last_mean"] = Field(
        "last",
        description="Encoder summary: the last "
        "hidden state, or the last beside the mean hidden state over all steps.",
    )
    pretrain_epochs: int = Field(
        25, ge=0, le=10_000, description="Epochs on reconstruction loss alone."
    )
    dec_epochs: int = Field(
        8,
        ge=0,
        le=10_000,
        description="Epochs on reconstruction + clustering loss "
        "(lstm_dec only); the target distribution is refreshed every epoch.",
    )
    cluster_weight: float = Field(
        0.1,
        ge=0.0,
        le=1e4,
        description="Weight of the DEC KL term against the reconstruction MSE (IDEC's gamma).",
    )
    alpha: float = Field(
        1.0, gt=0.0, le=1e3, description="Degrees of freedom of the Student-t kernel."
    )
    batch_size: int = Field(
        256,
        ge=1,
        le=1_000_000,
        description="Trajectories per batch (batches are cut from trajectories sorted by length).",
    )
    lr: float = Field(3e-3, gt=0.0, le=1.0, description="Adam learning rate.")
    dec_tol: float = Field(
        0.001,
        ge=0.0,
        le=1.0,
        description="Stop DEC early once fewer than this "
        "fraction of labels change between epochs (0 = run all dec_epochs).",
    )
    kmeans_n_init: int = Field(
        10, ge=1, le=1000, description="k-means restarts (best inertia kept)."
    )
    pretrain_tol: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="LSTM methods: stop pretraining early once an epoch "
        "lowers the reconstruction MSE by less than this fraction (0 = run all pretrain_epochs).",
    )
    device: Literal["cpu", "cuda", "auto"] = Field(
        "cpu",
        description="Where the neural methods (lstm_dec, lstm_kmeans, policy_mix, and "
        "bag_auto's fallback) train: 'cpu'; 'cuda' (a GPU; an error if none); 'auto' (a GPU "
        "where there is one). Their Ray tasks then ask for runner.gpus_per_task GPUs. The bag, "
        "greedy and k-means methods always run on the CPU.",
    )
    em_iterations: int = Field(
        10,
        ge=1,
        le=10_000,
        description="policy_mix: at most this many EM rounds (policies "
        "refitted to the labels, then every trajectory moved to its most likely policy).",
    )
    policy_steps: int = Field(
        50,
        ge=1,
        le=100_000,
        description="policy_mix: full-batch Adam steps per EM round (on policy_rows steps).",
    )
    policy_rows: int = Field(
        32768,
        ge=0,
        le=100_000_000,
        description="policy_mix: on a log with more steps than max(policy_rows, 64 x "
        "trajectories), the policies are fitted to a seeded sample of that many steps (every "
        "step is still scored); 0 = always every step.",
    )
    policy_lr: float = Field(0.01, gt=0.0, le=1.0, description="policy_mix: Adam learning rate.")
    em_tol: float = Field(
        0.005,
        ge=0.0,
        le=1.0,
        description="policy_mix: stop once fewer than this fraction of "
        "labels change in an EM round (0 = run all em_iterations).",
    )
    policy_min_share: float = Field(
        0.25,
        ge=0.0,
        le=1.0,
        description="policy_mix: a cluster left with fewer than this fraction of an equal share "
        "(trajectories / k) after an EM round is re-seeded with the half of the largest cluster "
        "that its policy explains worst (0 = never; docs/clustering.md).",
    )
    policy_time: bool = Field(
        False,
        description="policy_mix: the policies also see log(1 + t), the step's index in its "
        "trajectory, so styles that act by schedule (rock back first, then push) are told apart "
        "(docs/clustering.md). bag_auto ignores it: it fits policy_mix both ways where its first "
        "fit is not stable and keeps the clearly more stable one.",
    )
    policy_start: Literal["latent", "counters"] = Field(
        "latent",
        description="policy_mix's start: 'latent' (k-means on a per-trajectory style latent "
        "fitted with one shared policy pi(a | s, z): what a trajectory does where others do "
        "otherwise, not where its episode sent it) or 'counters' (k-means on the gain and mean "
        "of the features that never decrease; the default before 2026-11-29, docs/clustering.md).",
    )
    latent_dims: int = Field(
        4, ge=1, le=64, description="policy_start latent: dimensions of the style latent."
    )
    latent_beta: float = Field(
        0.1,
        gt=0.0,
        le=100.0,
        description="policy_start latent: weight of the latent's KL to its N(0, I) prior "
        "(1 = the evidence lower bound; lower lets the latent carry more of each trajectory).",
    )
    latent_steps: int = Field(
        500,
        ge=1,
        le=100_000,
        description="policy_start latent: Adam steps of a latent fit (4096 rows each; with "
        "latent_runs auto on a small log, 8 fits of half as many steps, 1024 rows each).",
    )
    latent_runs: int | Literal["auto"] = Field(
        "auto",
        description="policy_start latent: independent latent fits (side by side in one batched "
        "pass) whose k-means partitions are joined by their consensus. 'auto': 8 fits sharing "
        "one fit's budget (half latent_steps each, 1024 rows a step) on logs small enough that "
        "each still draws every row 16 times (up to 16,000 rows at the default steps: there one "
        "fit moves most with its seed), one fit on larger logs (docs/clustering.md). A number: "
        "that many fits of latent_steps each (1: the default before 2026-11-30).",
    )
    ceiling: bool = Field(
        True,
        description="Where the log has true styles: score the clustering against the supervised "
        "ceiling too (a panel of classifiers given the styles, 5-fold cross-validated; seconds on "
        "a small log, up to a minute on a large one). false = accuracy, ARI and NMI only.",
    )
    confidence_runs: int = Field(
        2,
        ge=0,
        le=20,
        description="Label-free confidence: refits of the method on random subsamples, compared "
        "with the clustering (stability; 0 = not measured). Each refit costs about one clustering.",
    )
    restarts: int = Field(
        1,
        ge=1,
        le=20,
        description="Label-free restarts: fit each of bag_auto's candidates (or the chosen "
        "method) this many times from different seeds and keep the most stable fit (needs "
        "confidence_runs > 0). Each restart costs one clustering and its refits; 1 = one fit.",
    )
    confidence_fraction: float = Field(
        0.8,
        gt=0.0,
        lt=1.0,
        description="Label-free confidence: the fraction of trajectories in each refit's subsample.",
    )
    silhouette_sample: int = Field(
        4000,
        ge=2,
        le=1_000_000,
        description="At most this many points "
        "(seeded sample) for the silhouette score, which is O(n^2).",
    )

    @field_validator("latent_runs")
    @classmethod
    def _latent_runs(cls, v: int | str) -> int | str:
        if isinstance(v, int) and not 1 <= v <= 64:
            raise ValueError(f"latent_runs must be auto or a number of fits in [1, 64], got {v}")
        return v

    @model_validator(mode="after")
    def _restarts_need_refits(self) -> ClusterConfig:
        if self.restarts > 1 and self.confidence_runs == 0:
            raise ValueError(
                f"restarts {self.restarts} keeps the most stable restart, and stability needs "
                "refits: set confidence_runs >= 1, or restarts: 1"
            )
        return self
