"""Reaching a tracking server: the fail-fast check of a tracking URI before any work starts, the
client, and the retry of transient failures that reports a down or hung server on one line."""

from __future__ import annotations

import contextlib
import http.client
import os
import re
import socket
import sqlite3
import time
import urllib.error
import urllib.request
from pathlib import Path

from pcpg_dist.common.disk import disk_full, is_disk_full
from pcpg_dist.common.errors import ServiceError, first_line, signals_held
from pcpg_dist.tracking.store import _sqlite_path

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


def end_quietly(client, run_id: str, status: str = "KILLED") -> None:
    """Mark ``run_id`` ended with ``status``, best effort (two tries, no error): for a run that is
    being abandoned because the command was interrupted or failed."""
    with contextlib.suppress(Exception):
        _retry(client.set_terminated, run_id, status, attempts=2)


def _retry(fn, *args, attempts: int = 5, **kwargs):
    """Call an MLflow client method, retrying transient failures with exponential backoff.

    When the attempts run out the failure becomes a one-line :class:`ServiceError` naming the
    server (the CLI prints it and exits 2): the local results are already written, and rerunning
    the same command logs them without recomputing anything.
    """
    from mlflow.exceptions import MlflowException

    uri = getattr(getattr(fn, "__self__", None), "tracking_uri", None)
    shown = uri or "(unknown URI)"
    for i in range(attempts):
        try:
            with writing_to(uri):
                return fn(*args, **kwargs)
        except (MlflowException, OSError) as e:
            if getattr(e, "error_code", "") in (
                "INVALID_PARAMETER_VALUE",
                "RESOURCE_ALREADY_EXISTS",
            ):
                raise
            if is_disk_full(e):  # retrying cannot help: one line, the local results are kept
                raise disk_full(_store_path(shown), what="the MLflow store") from None
            hung = _hangs(shown)
            if i == attempts - 1 or hung:
                first = _reason(e)
                what = "accepts connections but does not answer" if hung else "failed"
                raise ServiceError(
                    f"MLflow tracking server {_shown(shown)} {what} ({first}); local results are kept: "
                    f"rerun the same command once it is reachable to log them"
                ) from None
            time.sleep(min(2**i, 10))
    return None


def writing_to(uri: str | None):
    """A block that writes to the tracking store at ``uri``: for a database (not a server), Ctrl-C
    and SIGTERM wait until it ends, so an interrupted commit leaves no write lock behind."""
    return contextlib.nullcontext() if _served(uri) else signals_held()


def _served(uri: str | None) -> bool:
    """Whether the tracking store is behind a server (whose own process commits): an interrupt in
    the call is then safe, and a hung server must not make the command deaf to one."""
    if uri is None:
        import mlflow

        uri = mlflow.get_tracking_uri()
    return str(uri).lower().startswith(("http://", "https://", "databricks"))


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


def _store_path(uri: str) -> str:
    """Where a store writes: a SQLite store's file, or the URI itself."""
    return str(_sqlite_path(uri) or _shown(uri))
