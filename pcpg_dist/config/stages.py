"""Config models of the stages (Step A clustering, Step B ranking, Step C BC, evaluation, PBTG,
tuning, fan-out): pydantic only, so reading a YAML imports no stage and no torch.

Each stage module imports its model from here (``from pcpg_dist.config.stages import BCConfig``)
and re-exports it; never the reverse.
"""

from __future__ import annotations

import os
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from pcpg_dist.config.schema import StrictModel

DEFAULT_PS = (1.0, 0.75, 0.5, 0.25, 0.1)
MAX_SEED = 2**32 - 1  # NumPy's legacy seeding and torch.manual_seed both take any of these
MAX_EPISODE_STEPS = 100_000  # an episode cap; the paper's games need a few hundred at most
MAX_COUNT = 10_000_000  # episodes, epochs, trials: beyond this a run would take weeks


def machine_memory() -> int:
    """Physical memory of this machine in bytes (16 GiB when the OS does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 16 << 30


def gib(n_bytes: float) -> str:
    return f"{n_bytes / (1 << 30):.1f} GiB"


def check_memory(needed: float, what: str, lower: str) -> None:
    """Refuse a config whose largest single allocation (estimated from the config alone, before
    anything is allocated) would not fit in half this machine's memory; say what to lower."""
    budget = machine_memory() // 2
    if needed > budget:
        raise ValueError(
            f"{what} needs about {gib(needed)} of memory at once, more than half of this "
            f"machine's {gib(machine_memory())}: lower {lower}"
        )


class RankConfig(StrictModel):
    """How trajectories are scored, split and thresholded (Step B)."""

    beta: float = Field(
        0.1,
        gt=0.0,
        le=1.0,
        description=(
            "Penalty factor of Performance(X) for trajectories that do not end in a goal state "
            "(paper: 0.1)."
        ),
    )
    ps: tuple[float, ...] = Field(
        DEFAULT_PS,
        min_length=1,
        description=(
            "Fractions p of each cluster kept after ranking (top p by Performance); each in (0, 1]."
        ),
    )
    test_fraction: float = Field(
        0.2,
        gt=0.0,
        lt=1.0,
        description=(
            "Fraction of trajectories held out for testing, split before thresholding (every run "
            "evaluates its agents on them, so at least one is held out)."
        ),
    )
    split_seed: int = Field(
        0,
        ge=0,
        le=MAX_SEED,
        description=(
            "Seed of the train/test split; one split per environment, shared by all seeds' models so "
            "that PCPG and No Clustering are compared on the same unseen trajectories."
        ),
    )
    corruption_seed: int = Field(
        0,
        ge=0,
        le=MAX_SEED,
        description=(
            "Base seed of the label-corruption draws (combined with each model seed and level c)."
        ),
    )
    corruption_mode: Literal["wrong", "random"] = Field(
        "random",
        description=(
            "How a corrupted label is drawn: 'wrong' = uniformly among the k-1 other labels (c = 1: "
            "every label wrong); 'random' = uniformly among all k labels (c = 1: a random "
            "clustering, the No Clustering situation with 1/k of the data)."
        ),
    )
    style_margin: float = Field(
        0.0,
        ge=0.0,
        le=1e6,
        description=(
            "Style-aware Step B (not in the paper; 0 = the paper's ranking): a trajectory whose "
            "cluster is less than this many nats more likely than the next best ranks after every "
            "other trajectory of its cluster, in the training and test subsets alike, so the top p "
            "holds the cluster's skilled players of its style, not short trajectories that fit "
            "several styles. Needs a clusterer with a likelihood (greedy_mix, bag_auto on discrete "
            "states, policy_mix); 1 is the measured choice (docs/results.md)."
        ),
    )

    @field_validator("ps")
    @classmethod
    def _ps_in_range(cls, ps: tuple[float, ...]) -> tuple[float, ...]:
        for p in ps:
            if not 0.0 < p <= 1.0:
                raise ValueError(f"every p must lie in (0, 1], got {p}")
        if len(set(ps)) != len(ps):
            raise ValueError(f"ps has repeated values: {ps}")
        return ps


#: the clusterers that score each trajectory against every cluster (``ranking.style_margin``)
LIKELIHOOD_METHODS = ("greedy_mix", "bag_auto", "policy_mix")


NEURAL_CLUSTERERS = frozenset({"lstm_dec", "lstm_kmeans", "policy_mix", "bag_auto"})
"""Clustering methods that may train a network (``bag_auto`` falls back to ``lstm_dec`` on
continuous states): only these use ``clustering.device`` and ask Ray for a GPU."""


class ClusterConfig(StrictModel):
    """Step A settings. The default method, bag_auto (greedy_mix on discrete states), is the best
    label-free clusterer on 20 held-out random GridWorld layouts and falls back to the paper's
    lstm_dec on continuous states (see docs/clustering.md); lstm_dec stays available by name."""

    method: Literal[
        "lstm_dec",
        "lstm_kmeans",
        "summary_kmeans",
        "visits_kmeans",
        "bag_kmeans",
        "bag_mop",
        "greedy_mix",
        "bag_auto",
        "policy_mix",
    ] = Field(
        "bag_auto",
        description="lstm_dec: autoencoder + DEC loss (the paper); lstm_kmeans: k-means on "
        "pretrained latents; summary_kmeans: k-means on length, final and mean state; "
        "visits_kmeans: k-means (cosine) on which distinct states a trajectory visits (for "
        "discrete-state games; no network, seconds); bag_kmeans: weighted k-means (cosine) on "
        "distinct rows of visited states + state-actions + final state; bag_mop: a mixture of k "
        "policies (EM) started from bag_kmeans; greedy_mix: a mixture of k greedy policies with one "
        "uniform noise level, refined from bag_kmeans (discrete states); bag_auto: greedy_mix, "
        "or lstm_dec where states are continuous; "
        "policy_mix: a mixture of k neural policies (hard EM) started from k-means on the "
        "monotone features' gain and mean, for continuous states (docs/clustering.md).",
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
        50, ge=1, le=100_000, description="policy_mix: full-batch Adam steps per EM round."
    )
    policy_lr: float = Field(0.01, gt=0.0, le=1.0, description="policy_mix: Adam learning rate.")
    em_tol: float = Field(
        0.005,
        ge=0.0,
        le=1.0,
        description="policy_mix: stop once fewer than this fraction of "
        "labels change in an EM round (0 = run all em_iterations).",
    )
    silhouette_sample: int = Field(
        4000,
        ge=2,
        le=1_000_000,
        description="At most this many points "
        "(seeded sample) for the silhouette score, which is O(n^2).",
    )


class BCConfig(StrictModel):
    """The behavioural-cloning policy and its training (Step C)."""

    hidden_layers: int = Field(3, ge=0, le=8, description="Hidden layers of the MLP (paper: 3).")
    hidden_size: int = Field(5, ge=1, le=1024, description="Units per hidden layer (paper: 5).")
    activation: Literal["relu", "tanh"] = Field(
        "tanh",
        description=(
            "Hidden activation. tanh by default: with 5-unit layers relu units die and some seeds "
            "lose a style (measured on GridWorld, docs/bc_and_evaluation.md)."
        ),
    )
    epochs: int = Field(
        2000,
        ge=0,
        le=MAX_COUNT,
        description=(
            "Full-batch Adam steps (paper: '2000 episodes'); with batch_size, passes over the rows."
        ),
    )
    batch_size: int | None = Field(
        None,
        ge=1,
        le=10**9,
        description=(
            "Rows per Adam step; null (the paper) trains full batch. Set it where cells hold tens of "
            "thousands of distinct rows (Mario): one epoch is then one pass over a cell's rows, "
            "shuffled once from the cell's seed, in blocks of this many. Numba engine only."
        ),
    )
    lr: float = Field(0.01, gt=0.0, le=100.0, description="Adam learning rate (finite, > 0).")
    init: Literal["scratch", "no_clustering"] = Field(
        "scratch",
        description=(
            "scratch (the paper): every agent starts from its seeded initialisation. no_clustering: "
            "the No Clustering agents train first, then every other agent (per cluster, corrupted "
            "labels) starts from the No Clustering agent of its p and seed and trains "
            "finetune_epochs on its own rows, so it keeps what all players share (docs/mario.md)."
        ),
    )
    finetune_epochs: int | None = Field(
        None,
        ge=0,
        le=MAX_COUNT,
        description=(
            "Epochs of the agents that start from No Clustering (init no_clustering; null: epochs)."
        ),
    )
    betas: tuple[float, float] = Field(
        (0.9, 0.999), description="Adam beta1, beta2, each in [0, 1)."
    )
    eps: float = Field(1e-8, gt=0.0, le=1.0, description="Adam epsilon (finite, > 0).")
    device: Literal["cpu", "cuda", "auto"] = Field(
        "cpu",
        description=(
            "Where to train: 'auto' uses a GPU where there is one (the CPU with batch_size or engine "
            "numba, which run there only); 'cuda' fails without one. Ray tasks on a GPU ask for "
            "runner.gpus_per_task GPUs."
        ),
    )
    dtype: Literal["float32", "float64"] = Field("float32", description="Training precision.")
    engine: Literal["auto", "numba", "torch"] = Field(
        "auto",
        description=(
            "'numba': fused compiled CPU kernel (fastest on CPU, float32 only); 'torch': stacked "
            "baddbmm/bmm passes (runs on a GPU too); 'auto': numba on CPU in float32, else torch."
        ),
    )
    dedupe: bool = Field(
        True,
        description=(
            "Train on distinct (state, valid, action) rows weighted by their counts: same loss and "
            "gradient as the raw rows, far fewer rows where states repeat."
        ),
    )
    bucket_overhead_rows: int = Field(
        20000,
        ge=0,
        le=10**12,
        description=(
            "Padding (in cell-rows) worth one extra bucket; 0 = one bucket per distinct row count, "
            "very large = pad everything to the largest cell."
        ),
    )

    @field_validator("betas")
    @classmethod
    def _betas(cls, v: tuple[float, float]) -> tuple[float, float]:
        for i, b in enumerate(v):
            if not 0.0 <= b < 1.0:
                raise ValueError(f"Adam beta{i + 1} must lie in [0, 1), got {b}")
        return v

    @model_validator(mode="after")
    def _batch_engine(self) -> BCConfig:
        if self.batch_size is not None and (
            self.engine == "torch" or self.device == "cuda" or self.dtype != "float32"
        ):
            raise ValueError(
                "batch_size needs the numba engine (device cpu, dtype float32, "
                "engine auto or numba); set batch_size: null for the others"
            )
        if self.engine == "numba" and (self.device == "cuda" or self.dtype != "float32"):
            raise ValueError(
                f"engine numba runs on the CPU in float32 only (got device {self.device}, "
                f"dtype {self.dtype}); use engine auto or torch"
            )
        return self


class EvalConfig(StrictModel):
    """What the evaluation computes and how agents act in rollouts."""

    rollouts_per_policy: int = Field(
        100, ge=1, le=MAX_COUNT, description="Rollout episodes per trained policy."
    )
    greedy: bool = Field(
        True,
        description=(
            "Rollout actions: True = argmax over valid actions, False = sampled from the softmax."
        ),
    )
    max_steps: int = Field(
        100, ge=1, le=MAX_EPISODE_STEPS, description="Step limit of a rollout episode."
    )
    corruption_levels: tuple[float, ...] = Field(
        (0.0, 0.2, 0.4, 0.6, 0.8, 1.0),
        max_length=1000,
        description=(
            "Fractions c of cluster labels replaced by wrong ones in the corruption study; each in [0, 1]."
        ),
    )
    corruption_ps: tuple[float, ...] = Field(
        (1.0,),
        min_length=1,
        max_length=1000,
        description=(
            "p values of the corruption study's cells (default: all data, to isolate the labels)."
        ),
    )
    reward_p: float = Field(
        1.0,
        gt=0.0,
        le=1.0,
        description=(
            "p of the models whose rollouts give the headline reward distance (Table 3) and Fig. 8; "
            "the table lists every p. 1.0 = pi_k trained on its whole cluster (a small p keeps the "
            "shortest trajectories, which can be ones that skipped their style's bonus)."
        ),
    )
    rollout_seed: int = Field(
        0, ge=0, le=MAX_SEED, description="Base seed of the rollout generators."
    )
    figures: bool = Field(True, description="Write PNG figures beside the tables.")

    @field_validator("corruption_levels")
    @classmethod
    def _levels(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        for c in v:
            if not 0.0 <= c <= 1.0:
                raise ValueError(f"every corruption level c must lie in [0, 1], got {c}")
        if len(set(v)) != len(v):
            raise ValueError("corruption_levels has repeated values")
        return v

    @field_validator("corruption_ps")
    @classmethod
    def _ps(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        for p in v:
            if not 0.0 < p <= 1.0:
                raise ValueError(f"every p must lie in (0, 1], got {p}")
        if len(set(v)) != len(v):
            raise ValueError("corruption_ps has repeated values")
        return v

    @model_validator(mode="after")
    def _memory(self) -> EvalConfig:
        # a policy's rollouts run as one batch: states, actions and masks of every step kept
        check_memory(
            self.rollouts_per_policy * (self.max_steps + 1) * 64.0,
            f"one policy's {self.rollouts_per_policy} rollouts of up to {self.max_steps} steps",
            "evaluation.rollouts_per_policy or evaluation.max_steps",
        )
        return self


class PBTGConfig(StrictModel):
    """Q-learning and trajectory sampling for GridWorld."""

    episodes: Annotated[
        int, Field(ge=1, le=MAX_COUNT, description="Q-learning episodes per (E, R) (paper: 20000)")
    ] = 20_000
    gamma: Annotated[float, Field(gt=0, le=1, description="discount factor of Q-learning")] = 0.99
    learning_rate: Annotated[float, Field(gt=0, le=1, description="Q-learning step size")] = 0.5
    epsilon_start: Annotated[
        float, Field(ge=0, le=1, description="exploration rate at the first episode")
    ] = 1.0
    epsilon_end: Annotated[
        float, Field(ge=0, le=1, description="exploration rate at the last episode (linear decay)")
    ] = 0.05
    trajectories_per_style: Annotated[
        int, Field(ge=1, description="trajectories generated per (E, R) (paper: 8000)")
    ] = 8000
    dataset_per_style: Annotated[
        int,
        Field(
            ge=1,
            description="trajectories per style sampled into each environment's dataset D (paper: 1000)",
        ),
    ] = 1000
    noise_min: Annotated[
        float, Field(ge=0, le=1, description="lower end of the per-trajectory noise range")
    ] = 0.0
    noise_max: Annotated[
        float, Field(ge=0, le=1, description="upper end of the per-trajectory noise range")
    ] = 0.3
    max_steps: Annotated[
        int,
        Field(ge=1, le=MAX_EPISODE_STEPS, description="episode cap; reaching it counts as failure"),
    ] = 100
    initial_q: Annotated[
        float,
        Field(
            ge=-1e6,
            le=1e6,
            description="initial Q-value of every action; optimistic (>= the best return) "
            "makes Q-learning try every route before settling",
        ),
    ] = 200.0

    @model_validator(mode="after")
    def _ranges(self) -> PBTGConfig:
        if self.noise_min > self.noise_max:
            raise ValueError(
                f"noise_min ({self.noise_min}) must be <= noise_max ({self.noise_max})"
            )
        if self.dataset_per_style > self.trajectories_per_style:
            raise ValueError(
                f"dataset_per_style ({self.dataset_per_style}) must be <= "
                f"trajectories_per_style ({self.trajectories_per_style})"
            )
        # sample_trajectories keeps each trajectory's states and actions (int64) at full length
        check_memory(
            self.trajectories_per_style * (self.max_steps + 1) * 16.0,
            f"sampling {self.trajectories_per_style} trajectories of up to {self.max_steps} steps "
            f"per (layout, style)",
            "pbtg.trajectories_per_style or pbtg.max_steps",
        )
        return self


PARAMS = ("k", "lstm_hidden", "latent", "bc_layers", "bc_width")
#: trial parameter -> (config section, field) it sets in the tuned config
TARGETS = {
    "k": ("clustering", "k"),
    "lstm_hidden": ("clustering", "hidden_size"),
    "latent": ("clustering", "latent_size"),
    "bc_layers": ("bc", "hidden_layers"),
    "bc_width": ("bc", "hidden_size"),
}


class TuneConfig(StrictModel):
    """The search space, the objective and the study of `pcpg tune` (section ``tuning``)."""

    study_name: str | None = Field(
        None,
        description="Optuna study name (default: '<config name>-tune'); "
        "the same name in the same storage resumes the study.",
    )
    n_trials: int = Field(
        24,
        ge=1,
        le=MAX_COUNT,
        description="Finished trials (complete, pruned or failed) the study "
        "should hold; a rerun with a larger number continues it.",
    )
    parallel_trials: int = Field(
        2, ge=1, le=10_000, description="Trials in flight at once (Ray tasks)."
    )
    environments: list[str] | None = Field(
        None,
        description="Environments a trial trains on (default: "
        "the first one of the config); the score is their mean.",
    )
    k_range: tuple[int, int] = Field(
        (2, 8), description="Smallest and largest cluster count tried."
    )
    lstm_hidden_sizes: tuple[int, ...] = Field(
        (16, 32, 64),
        min_length=1,
        description=(
            "LSTM hidden sizes tried (clustering.hidden_size); one value = fixed, not searched."
        ),
    )
    latent_sizes: tuple[int, ...] = Field(
        (4, 8, 16),
        min_length=1,
        description=("Latent sizes tried (clustering.latent_size); one value = fixed."),
    )
    bc_layers_range: tuple[int, int] = Field(
        (1, 3), description="Fewest and most BC hidden layers tried."
    )
    bc_widths: tuple[int, ...] = Field(
        (5, 16, 32, 64),
        min_length=1,
        description=("BC hidden-layer widths tried (bc.hidden_size); one value = fixed."),
    )
    ps: tuple[float, ...] | None = Field(None, description="p values scored (default: ranking.ps).")
    seeds: list[int] | None = Field(
        None, description="BC seeds per trial (default: the first of seeds)."
    )
    penalty: float = Field(
        0.01,
        ge=0.0,
        description=(
            "lambda: accuracy one more cluster must gain to be worth it; score = accuracy - lambda (k - 1)."
        ),
    )
    min_cluster_fraction: float = Field(
        0.02,
        ge=0.0,
        lt=1.0,
        description=(
            "A trial whose smallest cluster holds less than this fraction of the training trajectories "
            "is pruned."
        ),
    )
    sampler_seed: int = Field(0, ge=0, le=MAX_SEED, description="Seed of the TPE sampler.")
    n_startup_trials: int = Field(
        8, ge=0, le=MAX_COUNT, description="Random trials before TPE models the results."
    )
    enqueue: list[dict[str, int]] = Field(
        [],
        description=("Parameter sets tried first, e.g. [{k: 4}] (missing parameters are sampled)."),
    )
    heartbeat_interval: int = Field(
        30, ge=1, le=86_400, description="RDB storage: seconds between heartbeats."
    )
    grace_period: int = Field(
        120,
        ge=1,
        le=10 * 86_400,
        description=(
            "RDB storage: a RUNNING trial without a heartbeat for this long is failed and retried."
        ),
    )
    max_retry: int = Field(
        2, ge=0, le=100, description="How often a trial whose driver or worker died is retried."
    )

    @field_validator("k_range", "bc_layers_range")
    @classmethod
    def _range(cls, v: tuple[int, int]) -> tuple[int, int]:
        if v[0] > v[1] or v[0] < 0:
            raise ValueError(f"a range must be [low, high] with 0 <= low <= high, got {list(v)}")
        return v

    @model_validator(mode="after")
    def _checks(self) -> TuneConfig:
        if self.k_range[0] < 1:
            raise ValueError("k_range must start at 1 or more")
        # the tried values must be ones the clustering and BC sections accept
        if self.k_range[1] > 1000 or self.bc_layers_range[1] > 8:
            raise ValueError(
                f"k_range ends at most at 1000 and bc_layers_range at 8, got {list(self.k_range)} "
                f"and {list(self.bc_layers_range)}"
            )
        for values, name, top in (
            (self.lstm_hidden_sizes, "lstm_hidden_sizes", 1024),
            (self.latent_sizes, "latent_sizes", 512),
            (self.bc_widths, "bc_widths", 1024),
        ):
            if min(values) < 1 or max(values) > top or len(set(values)) != len(values):
                raise ValueError(
                    f"{name} must be distinct sizes in 1..{top}, got {list(values)[:10]}"
                )
        if self.seeds is not None and any(not 0 <= s <= MAX_SEED for s in self.seeds):
            raise ValueError(f"tuning.seeds must be integers in 0..{MAX_SEED}")
        if self.ps is not None and any(not 0.0 < p <= 1.0 for p in self.ps):
            raise ValueError(f"tuning.ps: every p must lie in (0, 1], got {list(self.ps)[:10]}")
        for entry in self.enqueue:
            unknown = set(entry) - set(PARAMS)
            if unknown:
                raise ValueError(
                    f"enqueue: unknown parameter(s) {sorted(unknown)}; known: {list(PARAMS)}"
                )
            tops = {"k": 1000, "lstm_hidden": 1024, "latent": 512, "bc_layers": 8, "bc_width": 1024}
            for name, value in entry.items():
                low = 0 if name == "bc_layers" else 1
                if not low <= value <= tops[name]:
                    raise ValueError(f"enqueue: {name}={value} outside {low}..{tops[name]}")
        return self


class RunnerConfig(StrictModel):
    """How work is fanned out on Ray."""

    group_size: Annotated[
        int, Field(ge=1, le=1_000_000, description="BC cells trained together in one Ray task")
    ] = 125
    cpus_per_task: Annotated[
        int, Field(ge=1, le=4096, description="CPUs (and torch threads) per Ray task")
    ] = 1
    gpus_per_task: Annotated[
        float,
        Field(
            gt=0,
            le=64,
            description=(
                "GPUs each Ray task of a stage on a GPU asks for (clustering.device or bc.device cuda, or "
                "auto on a cluster with GPUs): a fraction shares one GPU among tasks (0.25: four at once), "
                "above 1 a whole number"
            ),
        ),
    ] = 0.25

    @field_validator("gpus_per_task")
    @classmethod
    def _whole_above_one(cls, v: float) -> float:
        if v > 1 and v != int(v):
            raise ValueError(
                f"must be at most 1 or a whole number (Ray shares a GPU only in fractions "
                f"of one), got {v:g}"
            )
        return v
