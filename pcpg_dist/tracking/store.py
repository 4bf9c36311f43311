"""The MLflow store itself: its default URI, file locks keyed by identity (beside a SQLite store or in
the user's cache folder for a server), creating or migrating a SQLite store once per process and
repairing one a killed process left half-created."""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import shutil
import sqlite3
import time
import warnings
from collections.abc import Iterator
from pathlib import Path

from pcpg_dist.common.disk import disk_full, is_disk_full
from pcpg_dist.common.errors import DataError, ServiceError, first_line

log = logging.getLogger("pcpg_dist.tracking")  # one logger for the whole package, as before

LOCK_TIMEOUT = 600.0  # s; a store lock is held for a find-or-create or one child's logging


def default_tracking_uri() -> str:
    env = os.environ.get("MLFLOW_TRACKING_URI")
    if env:
        return env
    return f"sqlite:///{Path.cwd().resolve() / 'mlflow.db'}"


def _sqlite_path(uri: str) -> Path | None:
    """The database file of a ``sqlite:///`` URI (None for servers and in-memory stores)."""
    if not uri.startswith("sqlite:///") or uri in ("sqlite:///", "sqlite:///:memory:"):
        return None
    return Path(uri.removeprefix("sqlite:///").split("?")[0])


def _lock_dir(uri: str) -> Path:
    db = _sqlite_path(uri)
    if db is not None:
        folder = db.parent / f".{db.name}.locks"
    else:  # a server: locks serialise this machine's processes; other machines merge afterwards
        cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
        folder = cache / "pcpg" / "mlflow-locks" / hashlib.sha256(uri.encode()).hexdigest()[:16]
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@contextlib.contextmanager
def store_lock(uri: str, key: str, timeout: float = LOCK_TIMEOUT) -> Iterator[None]:
    """An inter-process lock on one identity in one store (a fresh lock object per use, so two
    threads of one process exclude each other too; never nest two uses of the same key)."""
    from filelock import FileLock, Timeout

    path = _lock_dir(uri) / f"{hashlib.sha256(key.encode()).hexdigest()[:24]}.lock"
    try:
        with FileLock(str(path), timeout=timeout):
            yield
    except Timeout:
        raise ServiceError(
            f"waited {timeout:.0f} s for the MLflow store lock {path} ({key}); another pcpg "
            f"process holds it: let it finish or end it"
        ) from None


_prepared: set[str] = set()


@contextlib.contextmanager
def _quiet_migration() -> Iterator[None]:
    """MLflow and alembic log each schema step at INFO: nothing a user acts on."""
    loggers = [
        logging.getLogger(n)
        for n in ("mlflow.store.db.utils", "alembic", "alembic.runtime.migration")
    ]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.WARNING)
    try:
        with warnings.catch_warnings():  # alembic's notes on SQLite table rebuilds
            warnings.filterwarnings("ignore", module=r"alembic(\.|$)")
            yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


def _open_sqlite_store(uri: str) -> None:
    from mlflow.store.tracking.sqlalchemy_store import SqlAlchemyStore

    with _quiet_migration():
        SqlAlchemyStore(uri, _artifact_root(uri))


def _forget_engine(uri: str) -> None:
    """Close MLflow's cached engine of ``uri``: its pooled connections hold the old file open."""
    from mlflow.store.tracking.sqlalchemy_store import SqlAlchemyStore

    engine = SqlAlchemyStore._engine_map.pop(uri, None)
    if engine is not None:
        engine.dispose()


def _count_runs(db: Path) -> int:
    """Runs in a SQLite store, read without MLflow (0 when the table is missing or unreadable)."""
    try:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=30)
        try:
            return int(con.execute("SELECT count(*) FROM runs").fetchone()[0])
        finally:
            con.close()
    except sqlite3.Error:
        return 0


STORE_BYTES = 2 << 20  # a fresh MLflow 3.17 SQLite store: about 1.2 MB after its migrations


def prepare_store(uri: str) -> None:
    """Create or migrate a SQLite store once, under a lock, before anything logs to it.

    Two processes starting on a fresh folder would otherwise both run MLflow's schema migration
    and one fails. A store left half-created by a killed migration is repaired: when it holds no
    run it is moved aside (``mlflow.db.incomplete-<time>``) and created afresh; when it holds runs
    the migration is finished (a copy is kept first), and if that fails the error is one line.
    """
    db = _sqlite_path(uri)
    if db is None or uri in _prepared:
        return
    db.parent.mkdir(parents=True, exist_ok=True)
    with store_lock(uri, "store"):
        try:
            _open_sqlite_store(uri)
        except Exception as first:  # noqa: BLE001 - MLflow, SQLAlchemy and alembic errors alike
            if is_disk_full(first):  # not a half-created store: nothing is moved aside
                _forget_engine(uri)
                raise disk_full(db, STORE_BYTES, "the MLflow store") from None
            _repair_sqlite_store(uri, db, first)
    _prepared.add(uri)


def _repair_sqlite_store(uri: str, db: Path, error: Exception) -> None:
    stamp = time.strftime("%Y%m%d-%H%M%S")
    reason = first_line(error)
    runs = _count_runs(db)
    _forget_engine(uri)
    if runs == 0:
        aside = db.with_name(f"{db.name}.incomplete-{stamp}")
        os.replace(db, aside)
        for extra in ("-journal", "-wal", "-shm"):
            with contextlib.suppress(FileNotFoundError):
                os.replace(f"{db}{extra}", f"{aside}{extra}")
        log.warning(
            "the MLflow store %s was left half-created by an interrupted run (%s); it held no runs, "
            "so it was moved to %s and created afresh",
            db,
            reason,
            aside.name,
        )
        _open_sqlite_store(uri)
        return
    backup = db.with_name(f"{db.name}.backup-{stamp}")
    shutil.copy2(db, backup)
    try:
        from mlflow.store.db.utils import _upgrade_db, create_sqlalchemy_engine_with_retry

        with _quiet_migration():
            engine = create_sqlalchemy_engine_with_retry(uri)
            _upgrade_db(engine)
            engine.dispose()
        _open_sqlite_store(uri)
        log.warning(
            "the MLflow store %s had an unfinished schema migration (%s); finished it (copy kept "
            "at %s)",
            db,
            reason,
            backup.name,
        )
    except Exception as e:  # noqa: BLE001 - whatever the migration raised, one line
        again = first_line(e)
        raise ServiceError(
            f"the MLflow store {db} ({runs} runs) is damaged and could not be migrated ({again}); "
            f"a copy is at {backup}: move {db.name} away to start a fresh store"
        ) from None


def _artifact_root(uri: str) -> str | None:
    """On SQLite the artifacts go to ``mlruns/`` beside the database, as an absolute URI."""
    db = _sqlite_path(uri)
    return (db.parent / "mlruns").resolve().as_uri() if db is not None else None


def check_store_holds(target: str, uri: str) -> None:
    """Looking ``target`` up must not create a store: a ``sqlite:///`` file that does not exist
    holds no run (opening it would leave a 1 MB empty ``mlflow.db`` behind)."""
    db = _sqlite_path(uri)
    if db is not None and not db.is_file():
        raise DataError(
            f"{target!r} is neither a run's output folder nor an MLflow run: no such folder, and "
            f"no MLflow store at {uri}"
        )
