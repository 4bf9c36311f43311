"""MLflow tracking: one experiment per config name, one parent run per config, a child per environment.

Embedded default: ``sqlite:///<cwd>/mlflow.db`` with artifacts in ``<cwd>/mlruns``. For a team:
``MLFLOW_TRACKING_URI=http://host:5000`` (an ``mlflow server`` on PostgreSQL with proxied
artifacts, see ops/README.md). Everything here runs in the driver (threads allowed).

Laid out for review (docs/team-mode.md): the experiment carries ``mlflow.experimentKind`` so the
UI opens on its runs table; the parent run holds at most :data:`MAX_PARENT_METRICS` headline
metrics, curves over p and over the corruption level (one value per step), the summary figures
and a description; children hold each environment's detail. Std over seeds goes in a
``metrics.csv`` table, never as ``/std`` chart sections.

Identities and concurrency: a parent is found by its config's content hash (and its sweep run),
a child by (parent, environment, unit key), a sweep by its key. Every find-or-create runs under a
file lock keyed by that identity, beside a SQLite store or in the user's cache folder for a
server; a run created on another machine in the same instant is merged after the fact (the
earliest wins). Logging is idempotent: a parent's metrics go in one batch together with a digest
tag, so a rerun served from cache logs nothing again and leaves the original end time alone.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import http.client
import io
import json
import logging
import math
import os
import re
import shutil
import socket
import sqlite3
import tempfile
import time
import urllib.error
import urllib.request
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pcpg_dist
from pcpg_dist.common.errors import DataError, ServiceError, first_line
from pcpg_dist.common.provenance import git_commit, uv_lock_hash

# Progress bars of artifact transfers would interleave with ours in the terminal, and the fluent
# run that logs the agents model would print its URL on stdout, among the results.
os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
os.environ.setdefault("MLFLOW_SUPPRESS_PRINTING_URL_TO_STDOUT", "true")
# MLflow retries each HTTP call 7 times with doubling waits (~4 min a call, sized for a hosted
# service's rate limits) and _retry below tries each call 5 times on top, so a tracking server that
# died mid-sweep took 29 min to be reported (53 s now). Two retries a call ride out a restart; a
# value the user set wins.
os.environ.setdefault("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "2")

log = logging.getLogger(__name__)

ROLE, UNIT, CONFIG_HASH = "pcpg.role", "pcpg.unit_key", "pcpg.config_hash"
SWEEP_KEY, LOGGED, ARTIFACTS, AGENTS = (
    "pcpg.sweep_key",
    "pcpg.logged",
    "pcpg.artifacts_logged",
    "pcpg.agents_logged",
)
NOTE, PARENT, RUN_NAME = "mlflow.note.content", "mlflow.parentRunId", "mlflow.runName"
SAME_AS = "pcpg.same_as"  # a sweep's copy of a point another sweep ran (SweepTracker.add_reused)
# The MLflow 3 UI opens an experiment without this tag on its GenAI overview; the classic-ML
# value (mlflow/server/js: ExperimentKind.CUSTOM_MODEL_DEVELOPMENT) opens it on the runs table.
EXPERIMENT_KIND = ("mlflow.experimentKind", "custom_model_development")
MAX_PARENT_METRICS = 30
# Roles (tag ``pcpg.role``): a `pcpg run`'s run is the "parent" of its environments' runs; a `pcpg
# sweep`'s run ("sweep") is the parent of one "point" run per point, each the parent of its
# environments' runs. Points made before the role existed carry "parent" and are retagged when found.
PARENT_ROLE, POINT_ROLE, SWEEP_ROLE = "parent", "point", "sweep"
PARAM_BATCH, METRIC_BATCH = 100, 1000  # MLflow's limits per log_batch call
BOOKKEEPING = ("done.json", "*.lock", "*.tmp", ".*")  # cache bookkeeping, never an artifact
LOCK_TIMEOUT = 600.0  # s; a store lock is held for a find-or-create or one child's logging


# --------------------------------------------------------------------------- store and locks
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


HEALTH_TIMEOUT = 8.0  # s an MLflow server's /health may take before pcpg calls it hung


def check_tracking_uri(uri: str, timeout: float = HEALTH_TIMEOUT) -> None:
    """Fail fast (within ``timeout`` s), on one line naming the URI, when pcpg cannot use a tracking
    URI: a server that is down, a scheme MLflow does not store runs in, a folder store (MLflow 3
    refuses them), or a ``sqlite:///`` path that is not an MLflow database (pcpg would otherwise
    repair it as a half-created store, moving the user's file aside)."""
    scheme = uri.partition("://")[0].lower() if "://" in uri else ""
    forms = (
        "use sqlite:///PATH/mlflow.db, http(s)://HOST:PORT or postgresql+psycopg2://USER@HOST:PORT/DB, "
        "or --no-tracking"
    )
    if scheme in ("http", "https"):
        try:
            if (status := _health(uri, timeout)) != 200:
                raise ServiceError(f"MLflow server at {_shown(uri)} answered {status} on /health")
        except (
            http.client.HTTPException
        ) as e:  # something answers, not in HTTP (a Ray or database port)
            raise ServiceError(
                f"{_shown(uri)} does not answer in HTTP ({type(e).__name__}): is it the MLflow "
                f"server's port? set MLFLOW_TRACKING_URI to the server's http://HOST:PORT"
            ) from None
        except (urllib.error.URLError, OSError, TimeoutError, ValueError) as e:
            reason = getattr(e, "reason", e)
            raise ServiceError(
                f"MLflow tracking server {_shown(uri)} is unreachable ({reason}); start it or set "
                f"MLFLOW_TRACKING_URI to a reachable server (unset = local sqlite)"
            ) from None
    elif scheme == "sqlite":
        if (db := _sqlite_path(uri)) is not None:
            _check_sqlite_store(uri, db)
    elif scheme == "postgresql":
        raise ServiceError(
            f"tracking URI {_shown(uri)}: write postgresql+psycopg2://... (SQLAlchemy reads a "
            f"bare postgresql:// as the psycopg 3 driver, which pcpg does not ship)"
        )
    elif scheme.split("+")[0] in ("postgresql", "mysql", "mssql"):
        _check_port(uri, timeout)
        _check_database(uri, timeout)
    elif uri.startswith("databricks"):
        return
    elif scheme == "" and re.fullmatch(
        r"[A-Za-z0-9.-]+:\d+(/.*)?", uri
    ):  # HOST:PORT, the scheme left out
        raise ServiceError(
            f"tracking URI {_shown(uri)} has no scheme: write http://{uri} for an MLflow server; {forms}"
        )
    elif scheme in ("", "file"):
        if os.environ.get("MLFLOW_ALLOW_FILE_STORE", "").lower() not in ("1", "true"):
            raise ServiceError(
                f"tracking URI {_shown(uri)} is a folder store, which MLflow 3 no longer accepts; "
                f"{forms}"
            )
    else:
        raise ServiceError(
            f"tracking URI {_shown(uri)}: MLflow stores runs at no {scheme}:// address; {forms}"
        )


def _shown(uri: str) -> str:
    """A URI for a message: its password hidden, its length bounded."""
    uri = re.sub(r"(://[^:/@]*):[^@/]*@", r"\1:***@", uri)
    return repr(uri if len(uri) <= 200 else uri[:200] + "...")


def _check_port(uri: str, timeout: float) -> None:
    """A database server's port answers (SQLAlchemy would retry for minutes, in 169 lines)."""
    import urllib.parse

    try:
        url = urllib.parse.urlsplit(uri)
        host, port = (
            url.hostname or "localhost",
            url.port or {"mysql": 3306, "mssql": 1433}.get(url.scheme.split("+")[0], 5432),
        )
        socket.create_connection((host, port), timeout=timeout).close()
    except (OSError, ValueError) as e:
        raise ServiceError(
            f"tracking database {_shown(uri)} is unreachable ({e}); start it or fix the URI"
        ) from None


def _check_database(uri: str, timeout: float) -> None:
    """The database accepts pcpg (its driver is installed, the database and user exist): MLflow's
    own first connection retries for minutes and then prints a 100-line traceback."""
    import sqlalchemy
    from sqlalchemy.exc import NoSuchModuleError, SQLAlchemyError

    scheme = uri.partition("://")[0]
    args = {"connect_timeout": max(1, int(timeout))} if scheme.startswith("postgresql") else {}
    try:
        engine = sqlalchemy.create_engine(uri, connect_args=args)
    except (NoSuchModuleError, ImportError) as e:
        raise ServiceError(
            f"tracking URI {_shown(uri)}: its driver is not installed ({first_line(e, 200)}); "
            f"pcpg ships postgresql+psycopg2://"
        ) from None
    except (SQLAlchemyError, ValueError) as e:
        raise ServiceError(
            f"tracking URI {_shown(uri)} is not a database URL SQLAlchemy reads ({first_line(e, 200)})"
        ) from None
    try:
        with engine.connect():
            pass
    except SQLAlchemyError as e:
        cause = first_line(getattr(e, "orig", None) or e, 300)
        raise ServiceError(
            f"tracking database {_shown(uri)} refused the connection ({cause}); create the "
            f"database or user, or fix the URI"
        ) from None
    finally:
        engine.dispose()


def _check_sqlite_store(uri: str, db: Path) -> None:
    """``db`` is missing (MLflow creates it), empty, or an SQLite database whose tables are MLflow's."""
    if not db.exists():
        return
    if not db.is_file():
        raise ServiceError(
            f"tracking URI {_shown(uri)}: {db} is not a regular file; a sqlite:/// URI names "
            f"an MLflow database file (created if missing)"
        )
    with db.open("rb") as f:
        head = f.read(16)
    if head and head != b"SQLite format 3\x00":
        raise ServiceError(
            f"tracking URI {_shown(uri)}: {db} is not an SQLite database; point the URI at an "
            f"MLflow database or a new file"
        )
    try:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=30)
        try:
            tables = {
                t: {c[1] for c in con.execute(f"PRAGMA table_info('{t}')")}
                for (t,) in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")
            }
        finally:
            con.close()
    except sqlite3.Error:
        return  # unreadable: prepare_store's repair decides (a killed first migration looks like this)
    # A store whatever its MLflow version, or one left half-created, has these columns where it has
    # these tables; another program's database (its own 'runs' table, say) does not.
    own = {"runs": "run_uuid", "experiments": "experiment_id", "alembic_version": "version_num"}
    foreign = [
        t
        for t in tables
        if not t.startswith("sqlite_") and t not in own and not tables.keys() & own
    ]
    foreign += [t for t, col in own.items() if t in tables and col not in tables[t]]
    if foreign:
        raise ServiceError(
            f"tracking URI {_shown(uri)}: {db} is an SQLite database of another program (table "
            f"{foreign[0]!r} is not MLflow's); point the URI at an MLflow database or a new file"
        )


def _client(uri: str):
    from mlflow import MlflowClient

    return MlflowClient(tracking_uri=uri)


def _retry(fn, *args, attempts: int = 5, **kwargs):
    """Call an MLflow client method, retrying transient failures with exponential backoff.

    When the attempts run out the failure becomes a one-line :class:`ServiceError` naming the
    server (the CLI prints it and exits 2): the local results are already written, and rerunning
    the same command logs them without recomputing anything.
    """
    from mlflow.exceptions import MlflowException

    for i in range(attempts):
        try:
            return fn(*args, **kwargs)
        except (MlflowException, OSError) as e:
            if getattr(e, "error_code", "") in (
                "INVALID_PARAMETER_VALUE",
                "RESOURCE_ALREADY_EXISTS",
            ):
                raise
            uri = getattr(getattr(fn, "__self__", None), "tracking_uri", "(unknown URI)")
            hung = _hangs(uri)
            if i == attempts - 1 or hung:
                first = _reason(e)
                what = "accepts connections but does not answer" if hung else "failed"
                raise ServiceError(
                    f"MLflow tracking server {_shown(uri)} {what} ({first}); local results are kept: "
                    f"rerun the same command once it is reachable to log them"
                ) from None
            time.sleep(min(2**i, 10))
    return None


def _reason(e: BaseException) -> str:
    """A failed call's cause in a few words: the OS error urllib3 buries in a long retry text
    ("[Errno 111] Connection refused"), else the first line, cut at a word."""
    text = first_line(e, 10_000)
    if found := re.findall(r"\[Errno -?\d+\][^'\")\]]*", text):
        return found[-1].strip()
    return text if len(text) <= 200 else text[:200].rsplit(" ", 1)[0] + " …"


def _health(uri: str, timeout: float) -> int:
    """The HTTP status of an MLflow server's ``/health`` (raises what urllib raises)."""
    with urllib.request.urlopen(uri.rstrip("/") + "/health", timeout=timeout) as resp:
        return resp.status


def _hangs(uri: str) -> bool:
    """An HTTP server that takes a connection and leaves ``/health`` unanswered for HEALTH_TIMEOUT s.

    Each MLflow call to such a server waits MLFLOW_HTTP_REQUEST_TIMEOUT (120 s) per try, so
    retrying the call would cost minutes each time; a server that refuses connections (one
    restarting) or answers is retried as before.
    """
    if not uri.lower().startswith(("http://", "https://")):
        return False
    try:
        _health(uri, HEALTH_TIMEOUT)
        return False
    except TimeoutError:
        return True
    except urllib.error.URLError as e:
        return isinstance(e.reason, TimeoutError)
    except (OSError, ValueError):  # refused, reset, an HTTP error status: not hung
        return False


# --------------------------------------------------------------------------- logging helpers
def _log_params(
    client, run_id: str, params: dict[str, str], have: dict[str, str] | None = None
) -> None:
    """Params not yet on the run (MLflow refuses to change a logged param's value)."""
    from mlflow.entities import Param

    items = [Param(k, str(v)[:6000]) for k, v in sorted(params.items()) if k not in (have or {})]
    for i in range(0, len(items), PARAM_BATCH):
        _retry(client.log_batch, run_id, params=items[i : i + PARAM_BATCH])


def _log_once(
    client, run_id: str, points: list[tuple[str, float, int]], tags: dict[str, str]
) -> None:
    """Metrics and tags in as few batches as MLflow allows, the tags (the digest) in the last one."""
    from mlflow.entities import Metric, RunTag

    now = int(time.time() * 1000)
    items = [Metric(k, float(v), now, int(step)) for k, v, step in points]
    chunks = [items[i : i + METRIC_BATCH] for i in range(0, len(items), METRIC_BATCH)] or [[]]
    for i, chunk in enumerate(chunks):
        last = i == len(chunks) - 1
        _retry(
            client.log_batch,
            run_id,
            metrics=chunk,
            tags=[RunTag(k, v[:5000]) for k, v in tags.items()] if last else [],
        )


def _log_metrics(client, run_id: str, metrics: dict[str, float]) -> None:
    """Finite scalar metrics at step 0 (`pcpg tune`'s trial and study runs)."""
    _log_once(client, run_id, [(k, v, 0) for k, v in metrics.items() if _finite(v)], {})


def _digest(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _finite(v) -> bool:
    return isinstance(v, int | float) and math.isfinite(v)


def _copy_without_bookkeeping(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns(*BOOKKEEPING))
    return dst


def _log_folder(client, run_id: str, folder: Path, artifact_path: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        clean = _copy_without_bookkeeping(folder, Path(tmp) / "x")
        _retry(client.log_artifacts, run_id, str(clean), artifact_path)


def _std_table(metrics: dict[str, float]) -> str:
    """``metric,value,std`` rows: the std over seeds that the charts leave out."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["metric", "value", "std"])
    for k in sorted(metrics):
        if not k.endswith("/std") and _finite(metrics[k]):
            std = metrics.get(f"{k}/std")
            w.writerow([k, repr(float(metrics[k])), repr(float(std)) if _finite(std) else ""])
    return buf.getvalue()


# --------------------------------------------------------------------------- what is logged
_AXIS = re.compile(r"^(?P<rest>.+)/(?P<axis>[pc])(?P<x>\d+(?:\.\d+)?(?:e-?\d+)?)$")


def _steps(values: list[float]) -> tuple[dict[float, int], int]:
    """Integer MLflow steps for axis values in [0, 1]: 100 × x unless that merges two values."""
    for scale in (100, 1000, 10000, 100000):
        steps = {x: round(x * scale) for x in values}
        if len(set(steps.values())) == len(steps):
            return steps, scale
    return {x: i for i, x in enumerate(sorted(values))}, 0


def curves(metrics: dict[str, float]) -> tuple[dict[str, dict[float, float]], dict[str, float]]:
    """Split ``.../p<x>`` and ``.../c<x>`` metrics into curves ``{key: {x: value}}`` and scalars."""
    found: dict[str, dict[float, float]] = {}
    scalars: dict[str, float] = {}
    for k, v in metrics.items():
        if k.endswith("/std") or not _finite(v):
            continue
        m = _AXIS.match(k)
        if m:
            found.setdefault(f"{m['rest']}/by_{m['axis']}", {})[float(m["x"])] = float(v)
        else:
            scalars[k] = float(v)
    return found, scalars


def _curve_points(
    named: dict[str, dict[float, float]],
) -> tuple[list[tuple[str, float, int]], dict[str, int]]:
    points, scales = [], {}
    for key, curve in sorted(named.items()):
        steps, scale = _steps(list(curve))
        scales[key] = scale
        points += [(key, curve[x], steps[x]) for x in sorted(curve)]
    return points, scales


# The parent's scalars after PCPG and No Clustering at the largest and smallest p and the
# clustering trio, most important first (the budget keeps the head of the list).
_CLUSTERING = ("clustering/accuracy", "clustering/ceiling", "clustering/gap_to_ceiling")
_HEADLINE = (
    "clustering/ari",
    "clustering/nmi",
    "random/accuracy",
    "majority/accuracy",
    "pcpg/wins_over_baseline",
    "cross/diagonal_mean",
    "correlation/diagonal_mean",
    "corruption/baseline/accuracy",
)
# Curves over an axis: (source prefix, axis) -> chart key; the MLflow UI draws value against step.
PARENT_CURVES = {
    ("pcpg/accuracy", "p"): "accuracy_vs_p/pcpg",
    ("baseline/accuracy", "p"): "accuracy_vs_p/no_clustering",
    ("majority/accuracy", "p"): "accuracy_vs_p/majority_class",
    ("corruption/accuracy", "c"): "accuracy_vs_corruption/pcpg",
    ("corruption/accuracy_true_subsets", "c"): "accuracy_vs_corruption/pcpg_true_subsets",
}
# A headline scalar that can be the very number of a curve or per-p scalar already logged, e.g.
# `corruption/baseline/accuracy` (No Clustering over the corruption study's p, at c = 0) is
# `baseline/accuracy/p1` when that study uses p = 1 only, and `majority/accuracy` is the last point of
# the `accuracy_vs_p/majority_class` curve: each is logged only when it differs.
_MAYBE_SAME = {
    "corruption/baseline/accuracy": "baseline/accuracy",
    "majority/accuracy": "majority/accuracy",
    "random/accuracy": "random/accuracy",
}


def parent_metrics(
    result, timings: bool = True
) -> tuple[list[tuple[str, float, int]], dict[str, int]]:
    """The parent's (key, value, step) points: at most :data:`MAX_PARENT_METRICS` keys.

    Means over environments only (children hold each environment): PCPG and No Clustering at the
    largest and the smallest p, clustering accuracy / ceiling / gap, PCPG and No Clustering at the
    other p, then clustering ARI / NMI, baselines, stage timings (unless ``timings`` is false: a
    sweep's point, whose stages ran batched with the other points') and reward distances while the
    budget lasts; curves over p and over the corruption level as stepped metrics. A headline key
    equal to a per-p value already logged (as a scalar or a curve's point) is left out.
    """
    envs = tuple(f"{e}/" for e in getattr(result, "clustering", {}) or {})
    top = {k: v for k, v in result.metrics.items() if not k.startswith(envs)}
    by_axis, scalars = curves(top)
    named = {
        PARENT_CURVES[(k.rsplit("/by_", 1)[0], k[-1])]: c
        for k, c in by_axis.items()
        if (k.rsplit("/by_", 1)[0], k[-1]) in PARENT_CURVES and len(c) > 1
    }
    points, scales = _curve_points(named)
    ps = sorted(by_axis.get("pcpg/accuracy/by_p", {}), reverse=True)
    ends = list(dict.fromkeys([*ps[:1], *ps[-1:]]))
    per_p = [
        f"{m}/accuracy/p{p:g}"
        for p in [*ends, *(p for p in ps if p not in ends)]
        for m in ("pcpg", "baseline")
    ]
    stage_seconds = getattr(result, "stage_seconds", {}) if timings else {}
    timing = [f"time/{k}_seconds" for k in stage_seconds]
    values = {**top, **{f"time/{k}_seconds": v for k, v in stage_seconds.items()}}
    order = [
        *per_p[:4],
        *_CLUSTERING,
        *per_p[4:],
        *_HEADLINE,
        *timing,
        *sorted(k for k in scalars if k.startswith("reward_distance/")),
    ]
    budget = MAX_PARENT_METRICS - len(named)
    chosen: list[str] = []
    for k in dict.fromkeys(order):
        if len(chosen) == budget:
            break
        if k not in values or not _finite(values[k]):
            continue
        if k in _MAYBE_SAME and any(
            values.get(f"{_MAYBE_SAME[k]}/p{p:g}") == values[k]
            and (
                f"{_MAYBE_SAME[k]}/p{p:g}" in chosen
                or PARENT_CURVES.get((_MAYBE_SAME[k], "p")) in named
            )
            for p in ps
        ):
            continue
        chosen.append(k)
    return [(k, float(values[k]), 0) for k in chosen] + points, scales


def child_metrics(metrics: dict[str, float]) -> tuple[list[tuple[str, float, int]], dict[str, int]]:
    """An environment's detail: scalars as they are, per-p and per-level values as curves, no std."""
    by_axis, scalars = curves(metrics)
    ps = sorted(by_axis.get("pcpg/accuracy/by_p", {}), reverse=True)
    if ps:  # the headline p as scalars too, for the runs table and compare views
        scalars.update(
            {
                f"{m}/accuracy/p{ps[0]:g}": metrics[f"{m}/accuracy/p{ps[0]:g}"]
                for m in ("pcpg", "baseline")
                if _finite(metrics.get(f"{m}/accuracy/p{ps[0]:g}"))
            }
        )
    points, scales = _curve_points(by_axis)
    return [(k, v, 0) for k, v in sorted(scalars.items())] + points, scales


def _fmt(v) -> str:
    return f"{v:.3f}" if _finite(v) else "n/a"


def describe_run(cfg, result, scales: dict[str, int], command: str) -> str:
    """The parent's description (Markdown, shown on the run page): what ran, from where, the result."""
    m = result.metrics
    by_axis, _ = curves({k: v for k, v in m.items() if "/" in k})
    ps = sorted(by_axis.get("pcpg/accuracy/by_p", {}), reverse=True)
    envs = list(getattr(result, "clustering", {}) or [])
    # the result first: the runs table's Description column and the page's summary show the start
    lines = []
    if ps:
        at = [
            f"{_fmt(m.get(f'pcpg/accuracy/p{p:g}'))} vs {_fmt(m.get(f'baseline/accuracy/p{p:g}'))} at p = {p:g}"
            for p in dict.fromkeys([ps[0], ps[-1]])
        ]
        lines.append(
            f"PCPG vs No Clustering accuracy: {'; '.join(at)} (mean over environments; random "
            f"{_fmt(m.get('random/accuracy'))})."
        )
    if _finite(m.get("clustering/accuracy")):
        lines.append(
            f"Clustering accuracy {_fmt(m['clustering/accuracy'])}"
            + (
                f", gap to the supervised ceiling {_fmt(m['clustering/gap_to_ceiling'])}"
                if _finite(m.get("clustering/gap_to_ceiling"))
                else ""
            )
            + "."
        )
    elif _finite(m.get("clustering/silhouette")):
        lines.append(
            f"Clustering silhouette {_fmt(m['clustering/silhouette'])} (no true styles to compare)."
        )
    lines += [
        "",
        f"**{command or 'pcpg run'}** — experiment `{cfg.name}`, domain {getattr(cfg, 'domain', '?')}, "
        f"environments {', '.join(envs) or 'n/a'}, seeds "
        f"{', '.join(map(str, getattr(cfg, 'seeds', []) or []))}, config hash `{cfg.hash()}`.",
    ]
    charts = [
        f"`{k}`: step = {s} × {'p' if k.startswith('accuracy_vs_p') else 'c'}"
        for k, s in sorted(scales.items())
        if s
    ]
    if charts:
        lines += ["", "Curves: " + "; ".join(charts) + "."]
    cached = getattr(result, "cached_stages", None)
    if cached:
        lines.append(f"Stages served from cache: {', '.join(cached)}.")
    lines += [
        "",
        "Children: one run per environment (its tables, figures, models and curves). Std over "
        "seeds: `metrics.csv` artifacts. Tables and figures: `summary/`; the report: `report/report.html`.",
    ]
    return "\n".join(lines)


def ui_link(uri: str, run_id: str, ui: str = "http://127.0.0.1:5000") -> str:
    """The experiment's runs table in the MLflow UI (``ui``: where ``mlflow ui`` serves a local store).

    MLflow 3.17's UI picks GenAI or classic pages from its own workflow switch (saved in the
    browser, GenAI by default), not from the experiment's kind tag: the link names the classic
    workflow, so the first visit already opens on the runs table and the browser keeps it.
    """
    exp_id = _retry(_client(uri).get_run, run_id).info.experiment_id
    base = uri.rstrip("/") if uri.startswith(("http://", "https://")) else ui
    return f"{base}/#/experiments/{exp_id}/runs?workflowType=machine_learning"


# --------------------------------------------------------------------------- experiments and runs
def find_run(target: str, uri: str | None = None):
    """``(run, uri)``: ``target`` as an MLflow run id, or as an experiment name its newest top-level
    pcpg run (the run of a `pcpg run` or of a `pcpg sweep`; never one point of a sweep nor an
    environment's run), at ``uri`` (default: :func:`default_tracking_uri`). The URI is checked
    first, and a ``sqlite:///`` store that does not exist is reported, never created."""
    from mlflow.exceptions import MlflowException

    uri = uri or default_tracking_uri()
    check_store_holds(target, uri)
    check_tracking_uri(uri)
    client = _client(uri)
    try:
        return client.get_run(target), uri
    except MlflowException:
        exp = client.get_experiment_by_name(target)
        if exp is None:
            raise ServiceError(
                f"{target!r} is neither a run's output folder, an MLflow run id nor an "
                f"experiment name at {uri}"
            ) from None
        run = newest_top_level_run(client, exp.experiment_id)
        if run is None:
            raise ServiceError(
                f"experiment {target!r} at {uri} has no pcpg run or sweep yet"
            ) from None
        return run, uri


def newest_top_level_run(client, exp_id: str):
    """The experiment's newest live run of a `pcpg run` (role ``parent`` with no parent run: a
    sweep's points carry the sweep as theirs) or of a `pcpg sweep` (role ``sweep``); ``None`` if
    it has neither. MLflow's search has no "tag is unset", so a page of a sweep's points is skipped."""
    newest = None
    for role in (PARENT_ROLE, SWEEP_ROLE):
        token, found = None, None
        while found is None:
            page = _retry(
                client.search_runs,
                [exp_id],
                filter_string=f"tags.`{ROLE}` = '{role}'",
                order_by=["attributes.start_time DESC"],
                max_results=200,
                page_token=token,
            )
            found = next((r for r in page if PARENT not in r.data.tags), None)
            token = page.token
            if not token:
                break
        if found is not None and (
            newest is None or (found.info.start_time or 0) > (newest.info.start_time or 0)
        ):
            newest = found
    return newest


def sweep_points_of(sweep_run_id: str, uri: str) -> list:
    """The live point runs of a sweep run, oldest first (each a `pcpg run` of one point; role
    ``point``, or ``parent`` when an older pcpg made it)."""
    client = _client(uri)
    exp_id = _retry(client.get_run, sweep_run_id).info.experiment_id
    runs = [
        r
        for role in (POINT_ROLE, PARENT_ROLE)
        for r in _runs_with(client, exp_id, {ROLE: role, PARENT: sweep_run_id})
    ]
    return sorted(runs, key=lambda r: (r.info.start_time or 0, r.info.run_id))


def open_experiment(name: str, uri: str | None):
    """Check the server, prepare the store, get or create the experiment (tagged for the classic
    runs table); returns (uri, client, experiment id)."""
    from mlflow.exceptions import MlflowException

    uri = uri or default_tracking_uri()
    check_tracking_uri(uri)
    prepare_store(uri)
    client = _client(uri)
    exp = _retry(client.get_experiment_by_name, name)
    if exp is None:
        with store_lock(uri, f"experiment:{name}"):
            exp = _retry(client.get_experiment_by_name, name)
            if exp is None:
                try:
                    _retry(
                        client.create_experiment,
                        name,
                        artifact_location=_artifact_root(uri),
                        tags=dict([EXPERIMENT_KIND]),
                    )
                except MlflowException as e:  # created on another machine in the meantime
                    if getattr(e, "error_code", "") != "RESOURCE_ALREADY_EXISTS":
                        raise
                exp = _retry(client.get_experiment_by_name, name)
    if exp.tags.get(EXPERIMENT_KIND[0]) is None:
        _retry(client.set_experiment_tag, exp.experiment_id, *EXPERIMENT_KIND)
    return uri, client, exp.experiment_id


def _runs_with(client, exp_id: str, tags: dict[str, str], parent: str | None = ...) -> list:
    """Live runs carrying ``tags`` (and, unless ``...``, exactly this parent run), oldest first."""
    flt = " and ".join(f"tags.`{k}` = '{v}'" for k, v in tags.items())
    runs = _retry(client.search_runs, [exp_id], filter_string=flt, max_results=1000)
    if parent is not ...:
        runs = [r for r in runs if r.data.tags.get(PARENT) == parent]
    return sorted(runs, key=lambda r: (r.info.start_time or 0, r.info.run_id))


def _find_or_create(
    client,
    uri: str,
    exp_id: str,
    key: dict[str, str],
    parent: str | None,
    tags: dict[str, str],
    params: dict[str, str],
    legacy: dict[str, str] | None = None,
):
    """The run with identity ``key`` under ``parent``: found, or created under the identity's lock.

    Runs are found by their tags, never by name: a found run whose name differs from
    ``tags[RUN_NAME]`` (named by an older pcpg) is renamed. A run carrying ``legacy`` instead of
    ``key`` (an older pcpg's identity of the same run) is found too and retagged with ``key``.
    After creating, a search merges a twin made on another machine in the same instant: the
    earliest run wins and this process deletes its own (still empty) one.
    """
    lock = "run:" + json.dumps([exp_id, parent, key], sort_keys=True)
    with store_lock(uri, lock):
        found = _runs_with(client, exp_id, key, parent)
        if not found and legacy:
            found = _runs_with(client, exp_id, legacy, parent)
            for k, v in key.items():
                if found and found[0].data.tags.get(k) != v:
                    _retry(client.set_tag, found[0].info.run_id, k, v)
        if found:
            run = found[0]
            if RUN_NAME in tags and run.data.tags.get(RUN_NAME) != tags[RUN_NAME]:
                _retry(client.set_tag, run.info.run_id, RUN_NAME, tags[RUN_NAME])
            if run.info.status != "FINISHED":
                _retry(client.update_run, run.info.run_id, status="RUNNING")
                _log_params(client, run.info.run_id, params, have=run.data.params)
            return run.info.run_id, run.info.status == "FINISHED"
        all_tags = {**tags, **key, **({PARENT: parent} if parent else {})}
        mine = _retry(client.create_run, exp_id, tags=all_tags).info.run_id
        found = _runs_with(client, exp_id, key, parent)
        if found and found[0].info.run_id != mine:
            _retry(client.delete_run, mine)
            return found[0].info.run_id, found[0].info.status == "FINISHED"
        _log_params(client, mine, params)
        return mine, False


def short_keys(keys: list[str]) -> dict[str, str]:
    """Each dotted key's shortest tail that no other key ends with: ``clustering.k`` -> ``k``,
    unless another key (``pbtg.k``) ends in ``k`` too (then ``clustering.k``)."""
    out = {}
    for key in keys:
        parts = key.split(".")
        for n in range(1, len(parts) + 1):
            tail = ".".join(parts[-n:])
            if not any(o != key and (o == tail or o.endswith("." + tail)) for o in keys):
                break
        out[key] = tail
    return out


def point_label(params: dict[str, str]) -> str:
    """A sweep point's name in MLflow: its axis values, short keys first (``noise_max=0.3 k=4``),
    so the runs table, the sweep's child list and chart legends show them before any cut."""
    short = short_keys(list(params))
    return " ".join(f"{short[k]}={v}" for k, v in params.items())


def _provenance_tags(out_dir: Path | None = None) -> dict[str, str]:
    tags = {
        "pcpg.git_commit": git_commit(),
        "pcpg.version": pcpg_dist.__version__,
        "pcpg.uv_lock": uv_lock_hash(),
    }
    if out_dir is not None:
        tags["pcpg.output_dir"] = str(out_dir)
    return tags


def _command(out_dir: Path) -> str:
    try:
        return str(
            json.loads((Path(out_dir) / "summary" / "run.json").read_text()).get("command") or ""
        )
    except (OSError, ValueError, AttributeError):
        return ""


@dataclass
class Tracker:
    """The driver's handle on a config's MLflow experiment and parent run."""

    uri: str
    experiment_id: str
    parent_id: str
    config_hash: str
    cfg: object = None
    label: str = ""  # a sweep point's axis values, short ("noise_max=0.3 k=4"): its runs' names
    sweep_point: bool = False  # a point of a sweep: stage timings go on the sweep's run, not here

    @staticmethod
    def start(
        cfg,
        uri: str | None,
        out_dir: Path,
        *,
        parent_run_id: str | None = None,
        params: dict[str, str] | None = None,
    ) -> Tracker:
        """Find or create the config's parent run (keyed by its content hash).

        With ``parent_run_id`` (a sweep) the run is a nested child of that run, in its experiment,
        and ``params`` (the point's overrides, dotted keys) are logged as its params.
        """
        if parent_run_id:
            uri = uri or default_tracking_uri()
            check_tracking_uri(uri)
            prepare_store(uri)
            client = _client(uri)
            exp_id = _retry(client.get_run, parent_run_id).info.experiment_id
        else:
            uri, client, exp_id = open_experiment(cfg.name, uri)
        chash = cfg.hash()
        shown = " ".join(f"{k}={v}" for k, v in (params or {}).items())
        label = point_label(params or {}) if parent_run_id else ""
        tags = {
            RUN_NAME: label or f"{cfg.name}-{chash[:8]}",
            **_provenance_tags(out_dir),
            NOTE: f"`{cfg.name}`: running (config hash `{chash}`).",
        }
        if params:
            tags["pcpg.overrides"] = shown
        all_params = {**cfg.flat(), **{k: str(v) for k, v in (params or {}).items()}}
        role = POINT_ROLE if parent_run_id else PARENT_ROLE
        legacy = {ROLE: PARENT_ROLE, CONFIG_HASH: chash} if parent_run_id else None
        parent, _ = _find_or_create(
            client,
            uri,
            exp_id,
            {ROLE: role, CONFIG_HASH: chash},
            parent_run_id,
            tags,
            all_params,
            legacy=legacy,
        )
        return Tracker(uri, exp_id, parent, chash, cfg, label, bool(parent_run_id))

    def _children(self, env: str) -> list:
        return _runs_with(_client(self.uri), self.experiment_id, {"pcpg.env": env}, self.parent_id)

    def env_logged(self, env: str, unit_key: str) -> bool:
        return any(
            r.info.status == "FINISHED" and r.data.tags.get(UNIT) == unit_key
            for r in self._children(env)
        )

    def child_info(self, env: str, unit_key: str, cluster_metrics: dict[str, float]) -> dict:
        return {
            "uri": self.uri,
            "experiment_id": self.experiment_id,
            "parent_id": self.parent_id,
            "unit_key": unit_key,
            "config_hash": self.config_hash,
            "cluster_metrics": cluster_metrics,
            "label": self.label,
        }

    def finish(
        self, result, agents_dir: Path | None = None, report_dir: Path | None = None
    ) -> None:
        """Log the headline once: a rerun from cache finds the digest and logs nothing again."""
        client = _client(self.uri)
        run = _retry(client.get_run, self.parent_id)
        tags = run.data.tags
        points, scales = parent_metrics(result, timings=not self.sweep_point)
        # the results, not the timings: a rerun's summary stage takes its own time, and must not
        # make the run log everything again
        digest = _digest([pt for pt in points if not pt[0].startswith("time/")])
        if tags.get(LOGGED) != digest:
            note = (
                describe_run(self.cfg, result, scales, _command(result.out_dir))
                if self.cfg is not None
                else ""
            )
            _log_once(
                client,
                self.parent_id,
                points,
                {
                    LOGGED: digest,
                    **({NOTE: note} if note else {}),
                    "pcpg.curve_steps": json.dumps(scales),
                },
            )
        summary, report = Path(result.out_dir) / "summary", report_dir
        if tags.get(ARTIFACTS) != digest:
            if summary.is_dir():
                _log_folder(client, self.parent_id, summary, "summary")
                _retry(
                    client.log_text,
                    self.parent_id,
                    _std_table(result.metrics),
                    "summary/metrics.csv",
                )
            if report is not None and report.is_dir():
                _log_folder(client, self.parent_id, report, "report")
            _retry(client.set_tag, self.parent_id, ARTIFACTS, digest)
        if agents_dir is not None and not tags.get(AGENTS):
            self._log_agents(agents_dir)
            _retry(client.set_tag, self.parent_id, AGENTS, "yes")
        if run.info.status != "FINISHED":
            _retry(client.set_terminated, self.parent_id, "FINISHED")

    def _log_agents(self, agents_dir: Path) -> None:
        """The run's agents as one pyfunc model (see :mod:`pcpg_dist.tracking.agent_model`).

        The model's artifacts are ``<env>.npz`` + ``<env>.json`` (the run's torch files
        converted), so serving it needs numpy, pandas and mlflow only, pinned to the versions
        installed here: MLflow resolves and infers nothing while logging. MLflow 3.17 would also
        copy the uv.lock and pyproject.toml of the working directory into the model (torch and
        all, for ``--env-manager uv``) when it finds them; ``MLFLOW_UV_AUTO_DETECT=false`` keeps
        the model's environment to its own requirements. The fluent run is this parent, resumed
        ended by the fluent API (the first time only: ``finish`` skips it once logged).
        """
        import mlflow

        import pcpg_dist.tracking.agent_model as agent_model
        from pcpg_dist.reporting.onnx_export import load_agents_folder

        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp) / "agents"
            for env, cells in load_agents_folder(agents_dir).items():
                agent_model.write_env_agents(folder / env, env, cells)
            written = agent_model.read_all(folder)
            mlflow.set_tracking_uri(self.uri)
            before = os.environ.get("MLFLOW_UV_AUTO_DETECT")
            os.environ["MLFLOW_UV_AUTO_DETECT"] = "false"
            try:
                with agent_model.quiet_logging(), mlflow.start_run(run_id=self.parent_id):
                    mlflow.pyfunc.log_model(
                        name="agents",
                        python_model=agent_model.__file__,
                        artifacts={"agents": str(folder)},
                        signature=agent_model.signature(written),
                        input_example=agent_model.input_example(written),
                        conda_env=agent_model.conda_env(),
                    )
            finally:
                if before is None:
                    os.environ.pop("MLFLOW_UV_AUTO_DETECT", None)
                else:
                    os.environ["MLFLOW_UV_AUTO_DETECT"] = before

    def fail(self) -> None:
        with contextlib.suppress(Exception):  # best effort while already failing
            _retry(_client(self.uri).set_terminated, self.parent_id, "KILLED", attempts=2)


def log_environment(
    info: dict, env: str, out_dir: str, metrics: dict[str, float], model_paths: list[str]
) -> str:
    """One environment's child run: metrics (curves over p and c), tables, figures, models.

    Runs in the driver (any thread). Under the (parent, environment) lock: a FINISHED child with
    the same unit key is kept and nothing is logged; any other child of that environment (a
    half-written one of a killed run, or one from other settings) is deleted first.
    """
    uri, parent = info["uri"], info["parent_id"]
    client = _client(uri)
    with store_lock(uri, f"child:{parent}:{env}"):
        runs = _runs_with(client, info["experiment_id"], {"pcpg.env": env}, parent)
        # a sweep point's environments are named with the point: every point has an E1
        name = f"{env} · {info['label']}" if info.get("label") else env
        for run in runs:
            if run.info.status == "FINISHED" and run.data.tags.get(UNIT) == info["unit_key"]:
                if run.data.tags.get(RUN_NAME) != name:  # named by an older pcpg
                    _retry(client.set_tag, run.info.run_id, RUN_NAME, name)
                return run.info.run_id
        for run in runs:
            _retry(client.delete_run, run.info.run_id)
        merged = {**info["cluster_metrics"], **metrics}
        points, scales = child_metrics(merged)
        tags = {
            PARENT: parent,
            RUN_NAME: name,
            "pcpg.env": env,
            UNIT: info["unit_key"],
            ROLE: "environment",
            CONFIG_HASH: info["config_hash"],
            NOTE: f"Environment `{env}`: its evaluation tables and figures (`evaluation/`), trained "
            f"cells (`models/`), curves over p and c (steps: {json.dumps(scales)}), std over seeds "
            f"in `evaluation/metrics.csv`.",
        }
        run_id = _retry(client.create_run, info["experiment_id"], tags=tags).info.run_id
        _log_params(client, run_id, {"env": env})
        _log_once(client, run_id, points, {LOGGED: _digest(points)})
        _log_folder(client, run_id, Path(out_dir), "evaluation")
        _retry(client.log_text, run_id, _std_table(merged), "evaluation/metrics.csv")
        for path in model_paths:
            p = Path(path)
            for f in (p, p.with_suffix(".json")):
                if f.is_file():
                    _retry(client.log_artifact, run_id, str(f), f"models/{p.parent.name}")
        _retry(client.set_terminated, run_id, "FINISHED")
        return run_id


# --------------------------------------------------------------------------- sweeps
@dataclass
class SweepTracker:
    """A sweep's MLflow run: the parent of one run per point (:meth:`Tracker.start` with its id)."""

    uri: str
    experiment_id: str
    parent_id: str
    sweep_key: str

    @staticmethod
    def start(
        name: str, sweep_key: str, axes: dict[str, list], description: str, uri: str | None = None
    ) -> SweepTracker:
        """Find (by ``sweep_key``) or create the sweep run in experiment ``name``; idempotent."""
        uri, client, exp_id = open_experiment(name, uri)
        params = {f"sweep.{axis}": ",".join(map(str, values)) for axis, values in axes.items()}
        params["sweep.axes"] = ",".join(axes)
        params["sweep.points"] = str(math.prod(len(v) for v in axes.values()) if axes else 0)
        n = params["sweep.points"]
        tags = {
            RUN_NAME: f"sweep {' x '.join(short_keys(list(axes)).values())} ({n} points) {sweep_key[:8]}",
            NOTE: description,
            **_provenance_tags(),
        }
        run_id, _ = _find_or_create(
            client, uri, exp_id, {ROLE: SWEEP_ROLE, SWEEP_KEY: sweep_key}, None, tags, params
        )
        return SweepTracker(uri, exp_id, run_id, sweep_key)

    def finish(
        self,
        metrics: dict[str, float] | None,
        artifacts: list[Path],
        *,
        best_points: dict[str, str] | None = None,
        timings: dict[str, float] | None = None,
        note: str | None = None,
    ) -> None:
        """Log the sweep's metrics and artifacts once; a rerun with the same results logs nothing.

        ``best_points`` (metric -> the point that has it) become tags ``pcpg.best_point/<metric>``;
        ``note`` replaces the description; ``timings`` (``time/*`` metrics: the stage times of the
        points this call computed, all batched together) are logged with the results but left out
        of the digest, so a rerun that computes nothing logs nothing.
        """
        client = _client(self.uri)
        run = _retry(client.get_run, self.parent_id)
        points = [(k, float(v), 0) for k, v in sorted((metrics or {}).items()) if _finite(v)]
        files = sorted(
            (
                Path(a).name,
                hashlib.sha256(Path(a).read_bytes()).hexdigest() if Path(a).is_file() else "",
            )
            for a in artifacts
        )
        tags = {f"pcpg.best_point/{k}": v for k, v in sorted((best_points or {}).items())}
        if note:
            tags[NOTE] = note
        digest = _digest(points, files, tags)
        if run.data.tags.get(LOGGED) != digest:  # metrics and their digest in one batch
            times = [(k, float(v), 0) for k, v in sorted((timings or {}).items()) if _finite(v)]
            _log_once(client, self.parent_id, points + times, {**tags, LOGGED: digest})
        if (
            run.data.tags.get(ARTIFACTS) != digest
        ):  # files are overwritten, never appended: safe to redo
            for a in map(Path, artifacts):
                if a.is_dir():
                    _log_folder(client, self.parent_id, a, a.name)
                elif a.is_file():
                    _retry(client.log_artifact, self.parent_id, str(a))
            _retry(client.set_tag, self.parent_id, ARTIFACTS, digest)
        if run.info.status != "FINISHED":
            _retry(client.set_terminated, self.parent_id, "FINISHED")

    def add_reused(self, point_run_id: str) -> None:
        """List a point this call reused (an earlier sweep, e.g. before an axis was extended, ran
        it and logged it under its own sweep run) under this sweep too: a run of the same name,
        params and metrics (each metric's whole history, so its curves over p), tagged
        ``pcpg.same_as`` with the run it copies; its environments and artifacts stay on that run.
        Nothing when the point's run is already this sweep's child; idempotent."""
        client = _client(self.uri)
        src = _retry(client.get_run, point_run_id)
        if src.data.tags.get(PARENT) == self.parent_id:
            return
        name = src.data.tags.get(RUN_NAME, point_run_id)
        note = (
            f"{name}: reused by this sweep from run `{point_run_id}` of an earlier sweep, which "
            f"computed it; that run holds its environments, figures and agents. Metrics copied."
        )
        run_id, finished = _find_or_create(
            client,
            self.uri,
            self.experiment_id,
            {ROLE: POINT_ROLE, SAME_AS: point_run_id},
            self.parent_id,
            {RUN_NAME: name, NOTE: note},
            dict(src.data.params),
        )
        if finished:
            return
        points = [
            (k, m.value, m.step)
            for k in sorted(src.data.metrics)
            for m in _retry(client.get_metric_history, point_run_id, k)
        ]
        _log_once(client, run_id, points, {})
        _retry(client.set_terminated, run_id, "FINISHED")

    def fail(self) -> None:
        with contextlib.suppress(Exception):  # best effort while already failing
            _retry(_client(self.uri).set_terminated, self.parent_id, "KILLED", attempts=2)
