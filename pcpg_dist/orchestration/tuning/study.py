"""`pcpg tune`'s study: create or resume it, run its trials on Ray, write what it chose.

Tracking is not this layer's business: whoever runs the study (:mod:`pcpg_dist.api.tune`) may pass
:class:`StudyHooks`, told when the study starts, as trials finish, and how it ends.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from pcpg_dist.common.commands import command
from pcpg_dist.common.errors import ConfigError, DataError
from pcpg_dist.config.stages import TuneConfig
from pcpg_dist.orchestration.tuning.objective import trial_task
from pcpg_dist.orchestration.tuning.outputs import write_outputs
from pcpg_dist.orchestration.tuning.space import (
    SIZE_FIELDS,
    objective_key,
    searched_space,
    trial_environments,
    tune_settings,
)
from pcpg_dist.orchestration.tuning.storage import (
    Storage,
    fail_stale,
    finished_count,
    objective_key_of,
    open_storage,
    state_counts,
)
from pcpg_dist.orchestration.tuning.trials import TrialPool

if TYPE_CHECKING:
    from pcpg_dist.config import ExperimentConfig
    from pcpg_dist.domains.base import Unit


@dataclass
class TuneResult:
    """What `pcpg tune` produced."""

    study_name: str
    storage: str
    best_params: dict[str, int]
    best_value: float
    best_config: Path
    n_trials: dict[str, int]  # trials per state
    parent_run_id: str | None = None
    failed_stale: list[int] = field(default_factory=list)
    out_dir: Path | None = None


class StudyHooks(Protocol):
    """What a study tells its observer (the MLflow study tracker): ``started`` once the study is
    created, ``trials_finished`` whenever trials may have finished (it logs those not seen yet),
    then ``finished`` with the result or ``failed`` with a run status (KILLED, FAILED)."""

    @property
    def run_id(self) -> str | None:
        """The observer's record of the study (an MLflow parent run), for :class:`TuneResult`."""
        ...

    def started(self, cfg: ExperimentConfig, study_name: str, storage: str, study: Any) -> None: ...

    def trials_finished(self, study: Any) -> None: ...

    def finished(self, result: TuneResult) -> None: ...

    def failed(self, status: str) -> None: ...


TrialFn = Callable[..., dict[str, Any]]


def run_study(
    cfg: ExperimentConfig,
    storage_url: str | Storage | None = None,
    workdir: Path = Path("runs"),
    show_progress: bool = True,
    n_trials: int | None = None,
    study_name: str | None = None,
    out: Path | None = None,
    trial_fn: TrialFn = trial_task,
    hooks: StudyHooks | None = None,
) -> TuneResult:
    """Create or resume the study, run trials on Ray until it holds ``n_trials`` finished ones,
    and write the best parameters as a config `pcpg run` accepts. Ray must be initialised.

    ``storage_url``: a journal path or RDB URL, or a storage :func:`open_storage` opened already.
    ``trial_fn(datasets, cfg, tune, params, threads) -> {"value", "pruned", "metrics"}`` is the
    Ray task of one trial (a parameter so tests can make trials fail). ``hooks`` observe the study.
    """
    import ray

    tune = tune_settings(cfg, n_trials)
    gpus = _trial_gpus(cfg)
    name = study_name or tune.study_name or f"{cfg.name}-tune"
    storage = storage_url if isinstance(storage_url, Storage) else open_storage(storage_url, tune)
    key = objective_key(cfg, tune)
    known = objective_key_of(storage, name)
    if known is not None and known != key:
        raise ConfigError(
            f"study {name!r} in {storage.shown} was run with other data, search space or "
            f"objective settings; pass --study-name NEW to start another study"
        )
    out = _out_folder(cfg, name, workdir, out)
    data, tune = _trial_data(cfg, tune, workdir, show_progress)
    # every check of the user's input is behind us: only now is the study created and marked, so
    # a mistake never leaves a study that refuses the corrected command
    study, stale = _open_study(cfg, tune, storage, name, None if known is not None else key)
    data_ref = ray.put(data)
    threads = cfg.runner.cpus_per_task
    remote = ray.remote(num_cpus=threads, num_gpus=gpus, max_retries=tune.max_retry)(trial_fn)
    if hooks is not None:
        hooks.started(cfg, name, storage.shown, study)
    pool = TrialPool(
        study, storage, tune, lambda params: remote.remote(data_ref, cfg, tune, params, threads)
    )
    pool.stale = stale
    _drive(pool, name, show_progress, hooks)
    return _conclude(cfg, pool, name, out, hooks)


def _trial_gpus(cfg: ExperimentConfig) -> float:
    """A trial clusters and trains: it asks for a GPU where either stage runs on one (a setting no
    node can serve fails here, before the study is touched)."""
    from pcpg_dist.orchestration.nodes import node_gpus
    from pcpg_dist.orchestration.resources import bc_gpus, cluster_gpus

    most_gpus = node_gpus()
    return max(cluster_gpus(cfg, most_gpus), bc_gpus(cfg, most_gpus))


def _out_folder(cfg: ExperimentConfig, name: str, workdir: Path, out: Path | None) -> Path:
    """The default study's outputs in NAME/tuning, any other study's in a folder of its own (a
    second study's overwrote the first's there)."""
    default_out = Path(workdir).resolve() / cfg.name / "tuning"
    return (
        Path(out)
        if out
        else default_out
        if name == f"{cfg.name}-tune"
        else default_out / study_folder(name)
    )


def _trial_data(
    cfg: ExperimentConfig, tune: TuneConfig, workdir: Path, show_progress: bool
) -> tuple[dict[str, Unit], TuneConfig]:
    """The units a trial scores (loaded through the run's cache) and the space searched on them."""
    from pcpg_dist.orchestration.cache import Cache
    from pcpg_dist.orchestration.points import load_units

    the_units, _ = load_units(
        cfg, Cache(Path(workdir).resolve() / cfg.name / "cache"), show_progress
    )
    datasets = {u.name: u for u in the_units}
    envs = trial_environments(cfg, tune, list(datasets))
    tune, unused = searched_space(cfg, tune, [datasets[e] for e in envs])
    if any(
        SIZE_FIELDS[p] in cfg.tuning.model_fields_set for p in unused
    ):  # asked for, not only a default
        logging.getLogger(__name__).warning(
            "tuning: clustering.method %s does not use %s on this data: not searched (kept at the "
            "config's values)",
            cfg.clustering.method,
            ", ".join(unused),
        )
    return {e: datasets[e] for e in envs}, tune


def _open_study(
    cfg: ExperimentConfig, tune: TuneConfig, storage: Storage, name: str, new_key: str | None
) -> tuple[Any, list[int]]:
    """The study created or loaded, its sampler seeded, marked with ``new_key`` (a study new to
    the storage), stale trials failed and the config's points enqueued; and the stale trials."""
    import optuna

    study = optuna.create_study(
        study_name=name, storage=storage.storage, direction="maximize", load_if_exists=True
    )
    # a fresh study draws from sampler_seed; one resumed or extended (--n-trials more) from a seed
    # that also counts its trials, else its first draws repeat the earlier call's (same points,
    # answered from their results: budget spent, nothing explored)
    done_before = len(study.get_trials(deepcopy=False))
    seed = (
        tune.sampler_seed
        if not done_before
        else int(np.random.SeedSequence([tune.sampler_seed, done_before]).generate_state(1)[0])
    )
    study.sampler = optuna.samplers.TPESampler(seed=seed, n_startup_trials=tune.n_startup_trials)
    if new_key is not None:
        study.set_user_attr("pcpg.objective_key", new_key)
        study.set_user_attr("pcpg.config_name", cfg.name)
    stale = fail_stale(study, storage, tune, mine=set())
    queued = {tuple(sorted(t.params.items())) for t in study.get_trials(deepcopy=False)}
    for params in tune.enqueue:
        if tuple(sorted(params.items())) not in queued:
            study.enqueue_trial(params)
    return study, stale


def _drive(pool: TrialPool, name: str, show_progress: bool, hooks: StudyHooks | None) -> None:
    """Keep trials in flight until the study holds ``n_trials`` finished ones; an interrupted
    driver fails its trials in flight (rerun on resume) and tells the hooks before it re-raises."""
    from pcpg_dist.common.progress import progress_bar

    study, tune = pool.study, pool.tune
    try:
        with progress_bar(
            f"Optuna study {name}", total=tune.n_trials, enabled=show_progress
        ) as advance:
            for _ in range(min(finished_count(study), tune.n_trials)):
                advance()
            while True:
                pool.fill(advance)
                if not pool.in_flight:
                    break
                for ref in pool.wait():
                    pool.tell_done(ref, advance)
                    if hooks is not None:
                        hooks.trials_finished(study)
    except BaseException:
        pool.fail_in_flight()
        if hooks is not None:
            hooks.trials_finished(study)
            hooks.failed("KILLED")
        raise


def _conclude(
    cfg: ExperimentConfig, pool: TrialPool, name: str, out: Path, hooks: StudyHooks | None
) -> TuneResult:
    """The best trial written out as a config, or an error naming why no trial completed."""
    from optuna.trial import TrialState

    study, storage = pool.study, pool.storage
    if hooks is not None:
        hooks.trials_finished(study)  # trials answered from earlier results
    if not study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)):
        if hooks is not None:
            hooks.failed("FAILED")  # its MLflow run stayed RUNNING
        raise DataError(
            f"study {name!r}: no trial completed ({state_counts(study)}); see the trials' "
            f"'error' / 'pruned_reason' attributes ({command('optuna-dashboard', storage.shown)})"
        )
    best = study.best_trial
    # what the study chose (fixed dimensions are the config's own values, not a finding)
    best_params = {p: int(v) for p, v in best.params.items()}
    best_config = write_outputs(
        cfg, study, {**best.user_attrs.get("params_full", {}), **best_params}, out
    )
    result = TuneResult(
        name,
        storage.shown,
        best_params,
        float(best.value),
        best_config,
        state_counts(study),
        hooks.run_id if hooks is not None else None,
        pool.stale,
        out,
    )
    if hooks is not None:
        hooks.finished(result)
    return result


def study_folder(name: str) -> str:
    """A study name as one folder name: itself where it is plain, else made safe plus a short hash."""
    from pcpg_dist.common.run_folders import slug
    from pcpg_dist.config.checks import MAX_NAME, NAME_PATTERN

    plain = re.match(NAME_PATTERN, name) and ".." not in name and len(name) <= MAX_NAME
    return name if plain else slug(name[:60], name, fallback="study")
