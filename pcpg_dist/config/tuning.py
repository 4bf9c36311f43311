"""Config of `pcpg tune` (section ``tuning``): the search space, the objective and the study."""

from __future__ import annotations

from pydantic import Field, field_validator, model_validator

from pcpg_dist.config.limits import MAX_COUNT, MAX_SEED
from pcpg_dist.config.schema import StrictModel

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
