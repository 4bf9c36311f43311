"""Where a `pcpg tune` study lives, and what the driver does for trials whose driver died.

Default: a journal file in the working directory (one machine, one driver at a time: RUNNING
trials found at start belong to a driver that died and are failed and retried). For a team: an
RDB URL (PostgreSQL) with heartbeats; since ``optimize()`` is not used, the driver records
heartbeats for its in-flight trials and calls ``fail_stale_trials`` itself, and the storage's
:class:`~optuna.storages.RetryHeartbeatStaleTrialCallback` re-queues stale trials.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pcpg_dist.common.errors import ConfigError, ServiceError, first_line
from pcpg_dist.config.stages import TuneConfig

DEFAULT_STORAGE = "optuna_journal.log"  # in the working directory


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
    (:class:`~pcpg_dist.orchestration.tuning.journal.CheckedJournalBackend`).
    """
    import optuna

    url = url or str(Path.cwd() / DEFAULT_STORAGE)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    # heartbeats and the retry callback are marked experimental; they are what team mode needs
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    warnings.filterwarnings(
        "ignore", message="Heartbeat of storage is supposed to be used with Study.optimize"
    )
    if "://" not in url:
        return _open_journal(Path(url).resolve())
    return _open_rdb(rdb_url(url), tune)


def _open_journal(path: Path) -> Storage:
    """A journal file, replayed and checked to its end before the study touches it."""
    from optuna.storages.journal import JournalStorage

    from pcpg_dist.orchestration.tuning.journal import CheckedJournalBackend, short

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


def _open_rdb(url: str, tune: TuneConfig) -> Storage:
    """A database with heartbeats: the team's shared study storage."""
    from optuna.storages import RDBStorage, RetryHeartbeatStaleTrialCallback

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


def objective_key_of(storage: Storage, name: str) -> str | None:
    """The objective key recorded by study ``name``; None if there is no such study (yet)."""
    try:
        study_id = storage.storage.get_study_id_from_name(name)
    except KeyError:
        return None
    return storage.storage.get_study_user_attrs(study_id).get("pcpg.objective_key")


def state_counts(study: Any) -> dict[str, int]:
    """Trials per Optuna state name (``{"COMPLETE": 2, "PRUNED": 1}``)."""
    counts: dict[str, int] = {}
    for t in study.get_trials(deepcopy=False):
        counts[t.state.name] = counts.get(t.state.name, 0) + 1
    return counts


def finished_count(study: Any) -> int:
    """Trials that count towards ``n_trials``: complete, pruned or failed."""
    from optuna.trial import TrialState

    return len(
        study.get_trials(
            deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL)
        )
    )
