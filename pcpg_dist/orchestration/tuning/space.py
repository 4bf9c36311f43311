"""What a `pcpg tune` study searches: the parameters a trial draws, the dimensions the clusterer
ignores (fixed, so no budget is spent on them), and the key that says two studies are the same."""

from __future__ import annotations

import reprlib
from typing import TYPE_CHECKING, Any

from pcpg_dist.common.errors import ConfigError
from pcpg_dist.config.stages import MAX_COUNT, TARGETS, TuneConfig

if TYPE_CHECKING:
    from pcpg_dist.config import ExperimentConfig
    from pcpg_dist.domains.base import Unit


def suggest(trial: Any, tune: TuneConfig) -> dict[str, int]:
    """Draw one parameter set; a dimension with one value is fixed and not shown to the sampler."""

    def integer(name: str, low: int, high: int) -> int:
        return low if low == high else trial.suggest_int(name, low, high)

    def choice(name: str, values: tuple[int, ...]) -> int:
        return values[0] if len(values) == 1 else int(trial.suggest_categorical(name, list(values)))

    return {
        "k": integer("k", *tune.k_range),
        "lstm_hidden": choice("lstm_hidden", tune.lstm_hidden_sizes),
        "latent": choice("latent", tune.latent_sizes),
        "bc_layers": integer("bc_layers", *tune.bc_layers_range),
        "bc_width": choice("bc_width", tune.bc_widths),
    }


#: the clustering methods each network-size parameter acts on (the others ignore it), and the
#: tuning field that lists its values
USED_BY = {
    "lstm_hidden": ("lstm_dec", "lstm_kmeans", "policy_mix"),
    "latent": ("lstm_dec", "lstm_kmeans"),
}
SIZE_FIELDS = {"lstm_hidden": "lstm_hidden_sizes", "latent": "latent_sizes"}


def searched_space(
    cfg: ExperimentConfig, tune: TuneConfig, units: list[Unit]
) -> tuple[TuneConfig, list[str]]:
    """``tune`` with the sizes the clusterer ignores fixed at the config's own values (a trial
    would otherwise spend the study's budget on a dimension that changes nothing), and their names.
    ``bag_auto`` is resolved on the data: greedy_mix on discrete states, its fallback on continuous."""
    from pcpg_dist.config.clusterers import CLUSTERERS
    from pcpg_dist.stages.clustering import falls_back
    from pcpg_dist.stages.clustering.auto import fallback_for

    method = cfg.clustering.method
    if CLUSTERERS[method].continuous_fallback is not None:
        back = [u.clustered for u in units if falls_back(u.clustered)]
        method = fallback_for(method, back[0]) if back else "greedy_mix"
    unused = [
        p
        for p, methods in USED_BY.items()
        if method not in methods and len(getattr(tune, SIZE_FIELDS[p])) > 1
    ]
    fixed = {SIZE_FIELDS[p]: (getattr(cfg.clustering, TARGETS[p][1]),) for p in unused}
    return tune.model_copy(update=fixed), unused


def apply_params(cfg: ExperimentConfig, params: dict[str, int]) -> ExperimentConfig:
    """The config with a trial's parameters put in place (validated again, so bad values fail here)."""
    data = cfg.model_dump()
    for name, value in params.items():
        section, key = TARGETS[name]
        data[section][key] = int(value)
    if data["clustering"]["k"] < 2:  # one cluster: no other to corrupt labels into
        data["evaluation"]["corruption_levels"] = (0.0,)
    return type(cfg).model_validate(data)


def objective_key(cfg: ExperimentConfig, tune: TuneConfig) -> str:
    """Everything that changes a trial's numbers; a study is only resumed with the same key."""
    from pcpg_dist.common.keys import content_key
    from pcpg_dist.pipeline.declared import CODE_VERSION, data_key

    space = tune.model_dump(
        exclude={
            "study_name",
            "n_trials",
            "parallel_trials",
            "enqueue",
            "heartbeat_interval",
            "grace_period",
            "max_retry",
        }
    )
    return content_key(
        CODE_VERSION, data_key(cfg), cfg.clustering, cfg.bc, cfg.ranking, cfg.seed, cfg.seeds, space
    )


def trial_environments(cfg: ExperimentConfig, tune: TuneConfig, available: list[str]) -> list[str]:
    """The environments a trial scores (the data's first by default); a name the data lacks is
    refused before any study is created."""
    envs = tune.environments or available[:1]
    missing = [e for e in envs if e not in available]
    if missing:
        raise ConfigError(
            f"tuning.environments: {missing} not in the data's environments {available}"
        )
    return envs


def tune_settings(cfg: ExperimentConfig, n_trials: int | None = None) -> TuneConfig:
    """The config's tuning section with ``n_trials`` (``--n-trials``) in its place, checked as the
    config's own value is (a copy of a model is not validated again)."""
    if n_trials is None:
        return cfg.tuning
    if type(n_trials) is not int or not 1 <= n_trials <= MAX_COUNT:
        raise ConfigError(
            f"--n-trials must be at least 1 (and at most {MAX_COUNT}), got {reprlib.repr(n_trials)}"
        )
    return cfg.tuning.model_copy(update={"n_trials": n_trials})
