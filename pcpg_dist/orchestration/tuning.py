"""`pcpg tune`: choose k and the network sizes with Optuna, one Ray task per trial.

Why this shape:

- **The objective uses no true labels.** A trial clusters one (or a few) environments, trains
  the PCPG agents and scores their teacher-forced accuracy on held-out trajectories. Accuracy
  alone keeps rising with k (smaller, more homogeneous subsets are easier to imitate), so the score
  is ``mean PCPG accuracy - penalty * (k - 1)``: one more cluster must buy more than ``penalty``
  accuracy. A clustering whose smallest cluster holds less than ``min_cluster_fraction`` of the
  training trajectories is PRUNED (a cluster that small is noise, not a play-style). The gain
  over No Clustering is logged beside it but is not the objective: it would reward *small* BC
  networks, which No Clustering cannot fit a mixture with (see docs/tuning.md).
- **Ask/tell from the driver.** The driver keeps ``parallel_trials`` Ray tasks in flight, tells
  Optuna each result as it arrives, and logs every finished trial as an MLflow child run of one
  study parent run. A task that raises is told FAIL with its error in the trial's user attributes,
  and the study goes on.
- **Storage.** Default: a journal file in the working directory (one machine, one driver at a
  time: RUNNING trials found at start belong to a driver that died and are failed and retried).
  For a team: an RDB URL (PostgreSQL) with heartbeats; since ``optimize()`` is not used, the
  driver records heartbeats for its in-flight trials and calls ``fail_stale_trials`` itself, and
  the storage's :class:`~optuna.storages.RetryHeartbeatStaleTrialCallback` re-queues stale trials.
"""

from __future__ import annotations

import contextlib
import logging
import math
import re
import reprlib
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pcpg_dist.common.errors import ConfigError, DataError, ServiceError, first_line
from pcpg_dist.config.stages import MAX_COUNT, PARAMS, TARGETS, TuneConfig  # noqa: F401 - re-exported

if TYPE_CHECKING:
    from pcpg_dist.config import ExperimentConfig
    from pcpg_dist.domains.base import Unit

DEFAULT_STORAGE = "optuna_journal.log"  # in the working directory


# ----------------------------------------------------------------------------- search space
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
    ``bag_auto`` is resolved on the data: greedy_mix on discrete states, lstm_dec on continuous."""
    from pcpg_dist.stages.clustering.cluster import falls_back_to_lstm

    method = cfg.clustering.method
    if method == "bag_auto":
        method = "lstm_dec" if any(falls_back_to_lstm(u.clustered) for u in units) else "greedy_mix"
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
    from pcpg_dist.orchestration.cache import content_key
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


# ----------------------------------------------------------------------------- one trial
def trial_environments(cfg: ExperimentConfig, tune: TuneConfig, available: list[str]) -> list[str]:
    envs = tune.environments or available[:1]
    missing = [e for e in envs if e not in available]
    if missing:
        raise ConfigError(
            f"tuning.environments: {missing} not in the data's environments {available}"
        )
    return envs


def score_trial(
    datasets: dict[str, Unit], cfg: ExperimentConfig, tune: TuneConfig, params: dict[str, int]
) -> dict[str, Any]:
    """Cluster -> plan cells -> train -> held-out accuracy for each unit; no true labels.

    The same per-unit pipeline as `pcpg run` (:mod:`pcpg_dist.pipeline`): the same preprocessed
    input to Step A, the same held-out trajectories, the domain's own skill score. Returns
    ``{"value": score or None, "pruned": reason or None, "metrics": {...}}``. True styles, where
    the data has them, only go into the metrics (``*/ari``), never into the score.
    """
    from pcpg_dist.pipeline import cluster_unit, evaluate_unit, plan_unit
    from pcpg_dist.stages.bc import train_plan
    from pcpg_dist.stages.ranking import fmt

    trial_cfg = apply_params(cfg, params)
    k = trial_cfg.clustering.k
    rank = trial_cfg.ranking.model_copy(update={"ps": tuple(tune.ps or trial_cfg.ranking.ps)})
    seeds = tune.seeds or trial_cfg.seeds[:1]
    eval_cfg = trial_cfg.evaluation.model_copy(update={"figures": False, "corruption_levels": ()})
    metrics: dict[str, float] = {}
    pcpg, gain = [], []
    for env, unit in datasets.items():
        # no ceiling: it depends on the data alone, not on a trial's parameters
        clustering = cluster_unit(unit, trial_cfg.clustering, trial_cfg.seed, ceiling=False)
        labels = clustering.labels
        if "clustering/ari" in clustering.metrics:  # reported only, never scored
            metrics[f"{env}/ari"] = clustering.metrics["clustering/ari"]
        train_idx = unit.train_idx
        sizes = np.bincount(labels[train_idx], minlength=k)
        metrics[f"{env}/size_min_frac"] = float(sizes.min() / len(train_idx))
        metrics[f"{env}/silhouette"] = clustering.metrics.get("clustering/silhouette", float("nan"))
        if sizes.min() == 0 or sizes.min() / len(train_idx) < tune.min_cluster_fraction:
            return {
                "value": None,
                "metrics": metrics,
                "pruned": f"{env}: smallest cluster holds {int(sizes.min())} of {len(train_idx)} training "
                f"trajectories (< min_cluster_fraction {tune.min_cluster_fraction})",
            }
        cells = plan_unit(
            unit,
            labels,
            trial_cfg,
            rank_cfg=rank,
            seeds=seeds,
            corruption=False,
            margins=clustering.margins,
        )
        trained = train_plan(cells, trial_cfg.bc)
        ev = evaluate_unit(
            unit,
            labels,
            trained,
            trial_cfg,
            rank_cfg=rank,
            eval_cfg=eval_cfg,
            rollouts=False,
            extras=False,
            margins=clustering.margins,
        )
        acc = float(np.mean([ev[f"pcpg/accuracy/p{fmt(p)}"] for p in rank.ps]))
        base = float(np.mean([ev[f"baseline/accuracy/p{fmt(p)}"] for p in rank.ps]))
        metrics.update({f"{env}/pcpg_accuracy": acc, f"{env}/no_clustering_accuracy": base})
        pcpg.append(acc)
        gain.append(acc - base)
    metrics["pcpg_accuracy"], metrics["gain_over_no_clustering"] = (
        float(np.mean(pcpg)),
        float(np.mean(gain)),
    )
    value = metrics["pcpg_accuracy"] - tune.penalty * (k - 1)
    if not math.isfinite(value):
        raise DataError(f"trial {params}: the score is not finite (no test steps?)")
    metrics["score"] = value
    return {"value": value, "pruned": None, "metrics": metrics}


def trial_task(
    datasets: dict[str, Unit],
    cfg: ExperimentConfig,
    tune: TuneConfig,
    params: dict[str, int],
    threads: int,
) -> dict[str, Any]:
    """One trial as a Ray task: in-process and single-threaded unless given more CPUs."""
    from pcpg_dist.common.devices import set_threads

    set_threads(threads)
    start = time.perf_counter()
    out = score_trial(datasets, cfg, tune, params)
    out["metrics"]["trial_seconds"] = time.perf_counter() - start
    return out


# ----------------------------------------------------------------------------- storage
@dataclass
class Storage:
    """An opened study storage and what the driver must do for stale trials on it."""

    url: str
    storage: Any
    heartbeat: bool  # RDB: heartbeats + fail_stale_trials; journal: fail RUNNING trials at start

    @property
    def shown(self) -> str:
        """The URL without a password, for messages and MLflow tags."""
        if "://" in self.url and "@" in self.url:
            scheme, rest = self.url.split("://", 1)
            cred, host = rest.rsplit("@", 1)
            return f"{scheme}://{cred.split(':', 1)[0]}@{host}"
        return self.url


def rdb_url(url: str) -> str:
    """``postgresql://`` names the psycopg2 driver explicitly: SQLAlchemy 2.1 would pick psycopg 3,
    which is not installed (the project ships psycopg2-binary)."""
    return (
        "postgresql+psycopg2://" + url.removeprefix("postgresql://")
        if url.startswith("postgresql://")
        else url
    )


def open_storage(url: str | None, tune: TuneConfig) -> Storage:
    """A URL with ``://`` is an RDB (PostgreSQL for teams); anything else is a journal file path.

    A journal path must be a new file or an Optuna journal: any other file is refused, untouched
    (:class:`CheckedJournalBackend`).
    """
    import optuna
    from optuna.storages import RDBStorage, RetryHeartbeatStaleTrialCallback
    from optuna.storages.journal import JournalStorage

    from pcpg_dist.orchestration.optuna_journal import CheckedJournalBackend, short

    url = url or str(Path.cwd() / DEFAULT_STORAGE)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    # heartbeats and the retry callback are marked experimental; they are what team mode needs
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    warnings.filterwarnings(
        "ignore", message="Heartbeat of storage is supposed to be used with Study.optimize"
    )
    if "://" not in url:
        path = Path(url).resolve()
        if path.exists() and not path.is_file():  # /dev/null, a folder, a pipe
            raise ConfigError(
                f"cannot open the Optuna journal {path}: not a regular file; give a journal "
                f"file path or an RDB URL (postgresql://user@host:5432/db)"
            )
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            backend = CheckedJournalBackend(str(path))
            try:
                journal = JournalStorage(backend)  # replays the whole file
            except (KeyError, TypeError, ValueError, AssertionError) as e:
                # a line of the right shape whose fields Optuna's replay cannot use
                raise backend.not_a_journal(
                    backend.line, f"Optuna cannot replay it: {short(e)}"
                ) from None
            backend.check_read_to_end()
        except OSError as e:
            raise ServiceError(f"cannot open the Optuna journal {path}: {e.strerror}") from None
        return Storage(str(path), journal, heartbeat=False)
    url = rdb_url(url)
    try:
        rdb = RDBStorage(
            url,
            engine_kwargs={"pool_pre_ping": True},
            heartbeat_interval=tune.heartbeat_interval,
            grace_period=tune.grace_period,
            heartbeat_stale_trial_callback=RetryHeartbeatStaleTrialCallback(
                max_retry=tune.max_retry
            ),
        )
    except Exception as e:  # noqa: BLE001 - sqlalchemy/driver errors of many kinds
        shown = Storage(url, None, True).shown
        raise ServiceError(
            f"cannot open the Optuna storage {shown}: {first_line(e)}; --optuna-storage takes "
            f"a journal file path or a database URL (postgresql://USER@HOST:5432/DB)"
        ) from None
    return Storage(url, rdb, heartbeat=True)


def fail_stale(study: Any, storage: Storage, tune: TuneConfig, mine: set[int]) -> list[int]:
    """Fail RUNNING trials whose driver died and re-queue their parameters (up to max_retry).

    RDB: trials whose heartbeat is older than the grace period (any driver's). Journal: every
    RUNNING trial not in ``mine`` (one driver at a time uses a journal file).
    """
    from optuna.storages import RetryHeartbeatStaleTrialCallback, fail_stale_trials
    from optuna.trial import TrialState

    before = {t.number for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))}
    if storage.heartbeat:
        fail_stale_trials(study)
    else:
        retry = RetryHeartbeatStaleTrialCallback(max_retry=tune.max_retry)
        for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
            if t._trial_id in mine:
                continue
            study._storage.set_trial_user_attr(t._trial_id, "error", "stale: its driver stopped")
            if study._storage.set_trial_state_values(t._trial_id, TrialState.FAIL):
                retry(study, study._storage.get_trial(t._trial_id))
    after = {t.number for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))}
    return sorted(before - after)


# ----------------------------------------------------------------------------- the study
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


TrialFn = Callable[..., dict[str, Any]]


def _state_counts(study: Any) -> dict[str, int]:
    counts: dict[str, int] = {}
    for t in study.get_trials(deepcopy=False):
        counts[t.state.name] = counts.get(t.state.name, 0) + 1
    return counts


def _finished(study: Any) -> int:
    from optuna.trial import TrialState

    return len(
        study.get_trials(
            deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL)
        )
    )


def _error_text(exc: BaseException) -> str:
    """One line naming the trial's own exception (not Ray's wrapper)."""
    cause = getattr(exc, "cause", None) or exc
    text = (
        f"{type(cause).__name__}: {cause}".splitlines()[0] if str(cause) else type(cause).__name__
    )
    return text[:500]


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


def _objective_key_of(storage: Storage, name: str) -> str | None:
    """The objective key recorded by study ``name``; None if there is no such study (yet)."""
    try:
        study_id = storage.storage.get_study_id_from_name(name)
    except KeyError:
        return None
    return storage.storage.get_study_user_attrs(study_id).get("pcpg.objective_key")


def run_study(
    cfg: ExperimentConfig,
    storage_url: str | Storage | None = None,
    workdir: Path = Path("runs"),
    tracking_uri: str | None = None,
    track: bool = True,
    show_progress: bool = True,
    n_trials: int | None = None,
    study_name: str | None = None,
    out: Path | None = None,
    trial_fn: TrialFn = trial_task,
) -> TuneResult:
    """Create or resume the study, run trials on Ray until it holds ``n_trials`` finished ones,
    and write the best parameters as a config `pcpg run` accepts. Ray must be initialised.

    ``storage_url``: a journal path or RDB URL, or a storage :func:`open_storage` opened already.
    ``trial_fn(datasets, cfg, tune, params, threads) -> {"value", "pruned", "metrics"}`` is the
    Ray task of one trial (a parameter so tests can make trials fail).
    """
    import optuna
    import ray
    from optuna.storages import RetryHeartbeatStaleTrialCallback
    from optuna.trial import TrialState

    from pcpg_dist.common.progress import progress_bar
    from pcpg_dist.orchestration.cache import Cache
    from pcpg_dist.orchestration.points import load_units
    from pcpg_dist.orchestration.ray_pool import node_gpus
    from pcpg_dist.orchestration.resources import bc_gpus, cluster_gpus

    tune = tune_settings(cfg, n_trials)
    # a trial clusters and trains: it asks for a GPU where either stage runs on one (a setting no
    # node can serve fails here, before the study is touched)
    most_gpus = node_gpus()
    gpus = max(cluster_gpus(cfg, most_gpus), bc_gpus(cfg, most_gpus))
    name = study_name or tune.study_name or f"{cfg.name}-tune"
    storage = storage_url if isinstance(storage_url, Storage) else open_storage(storage_url, tune)
    key = objective_key(cfg, tune)
    known = _objective_key_of(storage, name)
    if known is not None and known != key:
        raise ConfigError(
            f"study {name!r} in {storage.shown} was run with other data, search space or "
            f"objective settings; pass --study-name NEW to start another study"
        )
    # the default study's outputs in NAME/tuning, any other study's in a folder of its own (a
    # second study's overwrote the first's there)
    default_out = Path(workdir).resolve() / cfg.name / "tuning"
    out = (
        Path(out)
        if out
        else default_out
        if name == f"{cfg.name}-tune"
        else default_out / _study_folder(name)
    )
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

    # every check of the user's input is behind us: only now is the study created and marked, so
    # a mistake never leaves a study that refuses the corrected command
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
    if known is None:
        study.set_user_attr("pcpg.objective_key", key)
        study.set_user_attr("pcpg.config_name", cfg.name)
    stale = fail_stale(study, storage, tune, mine=set())
    queued = {tuple(sorted(t.params.items())) for t in study.get_trials(deepcopy=False)}
    for params in tune.enqueue:
        if tuple(sorted(params.items())) not in queued:
            study.enqueue_trial(params)

    data_ref = ray.put({e: datasets[e] for e in envs})
    threads = cfg.runner.cpus_per_task
    remote = ray.remote(num_cpus=threads, num_gpus=gpus, max_retries=tune.max_retry)(trial_fn)
    tracker = StudyTracker.start(cfg, name, storage.shown, tracking_uri, study) if track else None

    # ObjectRef -> the trials waiting on it: a trial that draws the parameters of one in flight
    # shares its task, one that draws those of a finished trial reuses its result (deterministic)
    in_flight: dict[Any, list[Any]] = {}
    by_params: dict[tuple, Any] = {}
    last_check = time.monotonic()
    try:
        with progress_bar(
            f"Optuna study {name}", total=tune.n_trials, enabled=show_progress
        ) as advance:
            for _ in range(min(_finished(study), tune.n_trials)):
                advance()
            while True:
                while (
                    len(in_flight) < tune.parallel_trials
                    and _finished(study) + sum(map(len, in_flight.values())) < tune.n_trials
                ):
                    trial = study.ask()
                    if storage.heartbeat:
                        storage.storage.record_heartbeat(trial._trial_id)
                    params = suggest(trial, tune)
                    trial.set_user_attr("params_full", params)
                    key = tuple(sorted(params.items()))
                    if key in by_params:
                        in_flight[by_params[key]].append(trial)
                    elif _reuse(study, trial, key):
                        advance()
                    else:
                        ref = remote.remote(data_ref, cfg, tune, params, threads)
                        in_flight[ref], by_params[key] = [trial], ref
                if not in_flight:
                    break
                done, _ = ray.wait(
                    list(in_flight),
                    num_returns=1,
                    timeout=tune.heartbeat_interval if storage.heartbeat else None,
                )
                waiting = [t for ts in in_flight.values() for t in ts]
                if storage.heartbeat:
                    for t in waiting:
                        storage.storage.record_heartbeat(t._trial_id)
                    if time.monotonic() - last_check > tune.heartbeat_interval:
                        stale += fail_stale(
                            study, storage, tune, mine={t._trial_id for t in waiting}
                        )
                        last_check = time.monotonic()
                for ref in done:
                    by_params = {k: r for k, r in by_params.items() if r != ref}
                    for trial in in_flight.pop(ref):
                        _tell(study, trial, ref)
                        advance()
                    if tracker is not None:
                        tracker.log_finished(study)
    except BaseException:
        retry = RetryHeartbeatStaleTrialCallback(max_retry=tune.max_retry)
        for trial in (
            t for ts in in_flight.values() for t in ts
        ):  # interrupted: fail now, rerun on resume
            trial.set_user_attr("error", "interrupted: the driver stopped")
            study.tell(trial, state=TrialState.FAIL)
            retry(study, study._storage.get_trial(trial._trial_id))
        if tracker is not None:
            tracker.log_finished(study)
            tracker.fail()
        raise
    if tracker is not None:
        tracker.log_finished(study)  # trials answered from earlier results
    if not study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)):
        if tracker is not None:
            tracker.fail("FAILED")  # its MLflow run stayed RUNNING
        raise DataError(
            f"study {name!r}: no trial completed ({_state_counts(study)}); see the trials' "
            f"'error' / 'pruned_reason' attributes (uv run optuna-dashboard {storage.shown})"
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
        _state_counts(study),
        tracker.parent_id if tracker else None,
        stale,
        out,
    )
    if tracker is not None:
        tracker.finish(result)
    return result


def _study_folder(name: str) -> str:
    """A study name as one folder name: itself where it is plain, else made safe plus a short hash."""
    from pcpg_dist.common.run_folders import slug
    from pcpg_dist.config.domains import MAX_NAME, NAME_PATTERN

    plain = re.match(NAME_PATTERN, name) and ".." not in name and len(name) <= MAX_NAME
    return name if plain else slug(name[:60], name, fallback="study")


def _reuse(study: Any, trial: Any, key: tuple) -> bool:
    """Tell ``trial`` the outcome of a finished trial with the same parameters, if there is one."""
    from optuna.trial import TrialState

    for old in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED)):
        if tuple(sorted(old.user_attrs.get("params_full", {}).items())) == key:
            for k, v in old.user_attrs.items():
                trial.set_user_attr(k, v)
            trial.set_user_attr("duplicate_of", old.number)
            if old.state == TrialState.COMPLETE:
                study.tell(trial, old.value)
            else:
                study.tell(trial, state=TrialState.PRUNED)
            return True
    return False


def _tell(study: Any, trial: Any, ref: Any) -> None:
    """Report one finished Ray task to Optuna: COMPLETE, PRUNED (with reason) or FAIL (with error)."""
    import ray
    from optuna.trial import TrialState

    try:
        res = ray.get(ref)
    except Exception as e:  # noqa: BLE001 - any trial error: record it, the study goes on
        trial.set_user_attr("error", _error_text(e))
        study.tell(trial, state=TrialState.FAIL)
        return
    for k, v in res["metrics"].items():
        if isinstance(v, float) and math.isfinite(v):
            trial.set_user_attr(k, v)
    if res["pruned"]:
        trial.set_user_attr("pruned_reason", res["pruned"])
        study.tell(trial, state=TrialState.PRUNED)
    else:
        study.tell(trial, res["value"])


# ----------------------------------------------------------------------------- outputs
def best_config_data(cfg: ExperimentConfig, params: dict[str, int], where: Path) -> dict[str, Any]:
    """The config with the best parameters, as YAML data for a file in folder ``where``.

    Only what the study's config set, plus the tuned values: defaults stay defaults, so the file
    reads like the one the user wrote. Same name, so ``pcpg run`` of it works in the study's run
    folder and reuses the data the study cached there. No ``tuning`` section; every file or folder
    the config names (layouts, logs) relative to ``where``, so the file can move with its tree.
    """
    import os

    def portable(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: portable(v) for k, v in value.items()}
        if isinstance(value, str) and Path(value).is_absolute() and Path(value).exists():
            return os.path.relpath(value, where.resolve())
        return value

    tuned = apply_params(cfg, params)
    data = cfg.model_dump(mode="json", exclude={"tuning"}, exclude_unset=True)
    for name in params:
        section, key = TARGETS[name]
        value = getattr(getattr(tuned, section), key)
        if value != getattr(
            getattr(cfg, section), key
        ):  # unchanged (a fixed dimension): as the config has it
            data.setdefault(section, {})[key] = value
    if (
        tuned.evaluation.corruption_levels != cfg.evaluation.corruption_levels
    ):  # k = 1: see apply_params
        data.setdefault("evaluation", {})["corruption_levels"] = list(
            tuned.evaluation.corruption_levels
        )
    return {k: portable(v) if isinstance(v, dict) else v for k, v in data.items()}


def write_outputs(
    cfg: ExperimentConfig, study: Any, best_params: dict[str, int], out: Path
) -> Path:
    """``best_config.yaml`` (checked by loading it back), ``trials.csv`` and ``score_vs_k.png``."""
    import yaml

    from pcpg_dist.common.files import atomic_write_bytes
    from pcpg_dist.config import load_config

    out.mkdir(parents=True, exist_ok=True)
    path = out / "best_config.yaml"
    chosen = ", ".join(f"{k}={v}" for k, v in study.best_trial.params.items())
    header = (
        f"# Best parameters of Optuna study {study.study_name!r} ({chosen}),\n"
        f"# score {study.best_value:.4f}: the study's config with only these changed. `pcpg run` it with\n"
        f"# the study's --workdir to reuse the data the study cached under the same name.\n"
    )
    data = best_config_data(cfg, best_params, out)
    atomic_write_bytes(path, (header + yaml.safe_dump(data, sort_keys=False)).encode())
    load_config(path)  # what `pcpg run` will do: fail here, not later, if it is not loadable
    table = study.trials_dataframe(attrs=("number", "state", "value", "params", "user_attrs"))
    atomic_write_bytes(out / "trials.csv", table.to_csv(index=False).encode())
    _plot_score_vs_k(study, out / "score_vs_k.png")
    return path


def _plot_score_vs_k(study: Any, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from optuna.trial import TrialState

    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    k = np.array([t.user_attrs.get("params_full", t.params).get("k", 0) for t in done], float)
    score = np.array([t.value for t in done])
    acc = np.array([t.user_attrs.get("pcpg_accuracy", np.nan) for t in done])
    fig, ax = plt.subplots(figsize=(6, 4.6))
    jitter = np.random.default_rng(0).uniform(
        -0.12, 0.12, len(k)
    )  # seeded: same figure for same study
    ax.scatter(k + jitter, acc, marker="x", color="0.6", label="held-out PCPG accuracy")
    ax.scatter(k + jitter, score, color="C0", label="score = accuracy - penalty (k - 1)")
    for i, kk in enumerate(np.unique(k)):
        ax.plot(
            [kk - 0.3, kk + 0.3],
            [score[k == kk].max()] * 2,
            color="C1",
            label="best score at this k" if i == 0 else None,
        )
    ax.set_xlabel("k (clusters)")
    ax.set_ylabel("accuracy / score")
    ax.set_title(f"{study.study_name}: best k = {study.best_trial.params.get('k', '-')}")
    # below the axes: inside, it hid whichever points fell in its corner
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=2, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- MLflow
@dataclass
class StudyTracker:
    """One MLflow parent run per study (found again on resume), one child run per finished trial."""

    uri: str
    experiment_id: str
    parent_id: str
    logged: set[int]

    @staticmethod
    def start(
        cfg: ExperimentConfig, study_name: str, storage: str, uri: str | None, study: Any
    ) -> StudyTracker:
        from pcpg_dist.tracking.connection import _retry
        from pcpg_dist.tracking.runs import open_experiment
        from pcpg_dist.tracking.tags import ROLE

        uri, client, exp_id = open_experiment(cfg.name, uri)
        found = _retry(
            client.search_runs,
            [exp_id],
            filter_string=f"tags.`{ROLE}` = 'study' and tags.`pcpg.study` = '{study_name}'",
            max_results=1,
        )
        if found:
            parent = found[0].info.run_id
            _retry(client.update_run, parent, status="RUNNING")
        else:
            tags = {
                ROLE: "study",
                "pcpg.study": study_name,
                "pcpg.optuna_storage": storage,
                "mlflow.runName": study_name,
                "pcpg.config_hash": cfg.hash(),
            }
            parent = _retry(client.create_run, exp_id, tags=tags).info.run_id
        children = _retry(
            client.search_runs, [exp_id], filter_string=f"tags.`mlflow.parentRunId` = '{parent}'"
        )
        logged = {int(r.data.tags["pcpg.trial"]) for r in children if "pcpg.trial" in r.data.tags}
        return StudyTracker(uri, exp_id, parent, logged)

    def log_finished(self, study: Any) -> None:
        """A child run for every finished trial not logged yet (so a crash never loses one)."""
        from optuna.trial import TrialState

        from pcpg_dist.tracking.connection import _client, _retry
        from pcpg_dist.tracking.logged import _log_metrics, _log_params
        from pcpg_dist.tracking.tags import ROLE

        client = _client(self.uri)
        for t in study.get_trials(
            deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL)
        ):
            if t.number in self.logged:
                continue
            tags = {
                "mlflow.parentRunId": self.parent_id,
                "mlflow.runName": f"trial-{t.number}",
                ROLE: "trial",
                "pcpg.trial": str(t.number),
                "pcpg.trial_state": t.state.name,
            }
            for attr in ("error", "pruned_reason"):
                if attr in t.user_attrs:
                    tags[f"pcpg.{attr}"] = str(t.user_attrs[attr])[:5000]
            start = int(t.datetime_start.timestamp() * 1000) if t.datetime_start else None
            run_id = _retry(
                client.create_run, self.experiment_id, start_time=start, tags=tags
            ).info.run_id
            _log_params(client, run_id, {**t.user_attrs.get("params_full", {}), **t.params})
            metrics = {k: v for k, v in t.user_attrs.items() if isinstance(v, float)}
            if t.value is not None:
                metrics["score"] = t.value
            _log_metrics(client, run_id, metrics)
            end = int(t.datetime_complete.timestamp() * 1000) if t.datetime_complete else None
            _retry(
                client.set_terminated,
                run_id,
                "FAILED" if t.state == TrialState.FAIL else "FINISHED",
                end,
            )
            self.logged.add(t.number)

    def finish(self, result: TuneResult) -> None:
        from pcpg_dist.tracking.connection import _client, _retry
        from pcpg_dist.tracking.logged import _log_metrics

        client = _client(self.uri)
        _log_metrics(
            client,
            self.parent_id,
            {
                "best/score": result.best_value,
                **{f"best/{k}": float(v) for k, v in result.best_params.items()},
                **{f"trials/{k.lower()}": float(v) for k, v in result.n_trials.items()},
            },
        )
        if result.out_dir is not None:
            _retry(client.log_artifacts, self.parent_id, str(result.out_dir), "tuning")
        _retry(client.set_terminated, self.parent_id, "FINISHED")

    def fail(self, status: str = "KILLED") -> None:
        """Mark the study's run ended: KILLED when interrupted, FAILED when no trial completed."""
        from pcpg_dist.tracking.connection import _client, _retry

        with contextlib.suppress(Exception):  # best effort while already failing
            _retry(_client(self.uri).set_terminated, self.parent_id, status, attempts=2)
