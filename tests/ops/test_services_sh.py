"""ops/services.sh refuses, at once and in one line, what would otherwise hang or mislead.

Each case runs the real script (bash, as a subprocess) on ports 18700-18799 with its own state
and Ray temp dirs, and checks: exit code 2, a single stderr line `services.sh: ...` naming the
problem and the variable that fixes it, within seconds, and nothing left behind (no process, no
pid file, no state or Ray temp dir, no database). Databases made here are named `svc_test_*` and
dropped. PostgreSQL (127.0.0.1:5432, user postgres) is only needed to check that no database was
created and for the slow race test; without it those parts are skipped.
"""

from __future__ import annotations

import http.server
import os
import random
import re
import secrets
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SERVICES = ROOT / "ops" / "services.sh"
PG = {"host": "127.0.0.1", "port": 5432, "user": "postgres", "dbname": "postgres"}
PORTS = range(18700, 18800)
FAST = 20  # s; a refusal takes well under a second, but the machine may be loaded
_taken: set[int] = set()


def free_port() -> int:
    """A port in 18700-18799 that nothing listens on or holds right now, not handed out before."""
    ports = [p for p in PORTS if p not in _taken]
    random.shuffle(ports)
    for port in ports:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                continue
        with socket.socket() as s:
            try:
                s.bind(("0.0.0.0", port))
            except OSError:
                continue
        _taken.add(port)
        return port
    pytest.skip("no free port in 18700-18799")


class _Health(http.server.BaseHTTPRequestHandler):
    """Another server on the port: answers 200 to every GET, /health included."""

    def do_GET(self):
        body = b"OK"
        self.send_response(200)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args):
        pass


def http_server(port: int) -> http.server.ThreadingHTTPServer:
    server = http.server.ThreadingHTTPServer(("127.0.0.1", port), _Health)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def pg_conn():
    """An autocommit connection to the local PostgreSQL, or None."""
    try:
        import psycopg2

        conn = psycopg2.connect(connect_timeout=5, **PG)
    except Exception:
        return None
    conn.autocommit = True
    return conn


def db_exists(name: str) -> bool | None:
    conn = pg_conn()
    if conn is None:
        return None
    try:
        with conn.cursor() as cur:
            cur.execute("SELECT 1 FROM pg_database WHERE datname = %s", (name,))
            return cur.fetchone() is not None
    finally:
        conn.close()


def drop_db(name: str) -> None:
    conn = pg_conn()
    if conn is not None:
        with conn.cursor() as cur:
            cur.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        conn.close()


def processes_mentioning(*markers: str) -> list[str]:
    """Command lines of running processes that contain any of ``markers``."""
    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            cmd = (
                Path(f"/proc/{pid}/cmdline")
                .read_bytes()
                .replace(b"\0", b" ")
                .decode(errors="replace")
            )
        except OSError:
            continue
        if any(m in cmd for m in markers):
            found.append(f"{pid}: {cmd[:200]}")
    return found


@pytest.fixture
def svc(tmp_path):
    """Run services.sh with a private state dir, Ray temp dir and MLflow database name."""
    state = tmp_path / "services"
    ray_temp = Path(f"/tmp/svc-ray-{secrets.token_hex(4)}")  # short: Ray's Unix sockets live there
    db = f"svc_test_{secrets.token_hex(4)}"
    base_env = {k: v for k, v in os.environ.items() if not k.startswith("PCPG_")}
    base_env.update(
        PCPG_BIN=str(Path(sys.executable).parent),
        PCPG_SERVICES_DIR=str(state),
        PCPG_PG_URL=f"postgresql+psycopg2://{PG['user']}@{PG['host']}:{PG['port']}",
        PCPG_MLFLOW_DB=db,
        PCPG_OPTUNA_DB=f"{db}_optuna",
        PCPG_MLFLOW_WORKERS="1",
        PCPG_RAY_AUTH_MODE="disabled",
        PCPG_RAY_TEMP=str(ray_temp),
        # were a refusal to regress, fail within a minute instead of 3 x 300 s
        PCPG_START_TIMEOUT="60",
        PCPG_RAY_START_ATTEMPTS="1",
        PCPG_MLFLOW_PORT=str(free_port()),
        PCPG_RAY_PORT=str(free_port()),
    )

    class Svc:
        env = base_env
        dbs = (db, f"{db}_optuna")

        def run(self, *args: str, timeout: float = 150, **env: str):
            t0 = time.monotonic()
            res = subprocess.run(
                ["bash", str(SERVICES), *args],
                env={**base_env, **env},
                text=True,
                capture_output=True,
                timeout=timeout,
            )
            res.seconds = time.monotonic() - t0
            return res

        def assert_refused(self, res, *words: str, within: float = FAST) -> str:
            """Exit 2, one stderr line `services.sh: ...` with ``words``, quickly, nothing left."""
            out = f"rc={res.returncode}\nstdout:\n{res.stdout}\nstderr:\n{res.stderr}"
            assert res.returncode == 2, out
            lines = res.stderr.strip().splitlines()
            assert len(lines) == 1, out
            assert lines[0].startswith("services.sh: "), out
            for word in words:
                assert word in lines[0], f"{word!r} not in: {lines[0]}"
            assert res.seconds < within, f"took {res.seconds:.1f} s:\n{out}"
            self.assert_nothing_left()
            return lines[0]

        def assert_nothing_left(self, keep_state: bool = False) -> None:
            left = processes_mentioning(str(state), str(ray_temp))
            assert not left, f"left running: {left}"
            assert not list(state.glob("*.pid")), f"pid files left: {list(state.glob('*.pid'))}"
            if not keep_state:
                assert not state.exists(), f"state dir created: {sorted(state.rglob('*'))}"
            assert not ray_temp.exists(), "Ray temp dir created"

        def assert_no_databases(self) -> None:
            for name in self.dbs:
                assert db_exists(name) in (False, None), f"database {name} was created"

    s = Svc()
    try:
        yield s
    finally:
        subprocess.run(
            ["bash", str(SERVICES), "stop", "all"], env=base_env, capture_output=True, timeout=120
        )
        for name in s.dbs:
            drop_db(name)
        shutil.rmtree(ray_temp, ignore_errors=True)


# ---------------------------------------------------------------------------- 1: MLflow port
def test_start_mlflow_refuses_port_held_by_another_server(svc):
    """Another server answering /health on the port used to pass for MLflow ("mlflow is up")."""
    port = int(svc.env["PCPG_MLFLOW_PORT"])
    other = http_server(port)
    try:
        res = svc.run("start", "mlflow")
    finally:
        other.shutdown()
        other.server_close()
    svc.assert_refused(res, f"port {port}", "already in use", "PCPG_MLFLOW_PORT")
    assert "mlflow is up" not in res.stdout
    svc.assert_no_databases()


def test_start_mlflow_refuses_plain_listener(svc):
    port = int(svc.env["PCPG_MLFLOW_PORT"])
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))
        s.listen()
        res = svc.run("start", "mlflow")
    svc.assert_refused(res, f"port {port}", "PCPG_MLFLOW_PORT")
    svc.assert_no_databases()


@pytest.mark.slow
@pytest.mark.services
def test_start_mlflow_detects_port_taken_after_the_check(svc):
    """The port is free at the check and taken before MLflow binds it: the script must not take
    the other server's /health answer for its own; it ends in one line and leaves no process."""
    if pg_conn() is None:
        pytest.skip("PostgreSQL is not reachable at 127.0.0.1:5432 as postgres")
    port = int(svc.env["PCPG_MLFLOW_PORT"])
    pidfile = Path(svc.env["PCPG_SERVICES_DIR"]) / "mlflow.pid"
    squatter: list = []
    stop = threading.Event()

    def squat():  # take the port as soon as services.sh has launched its server
        while not stop.is_set():
            if pidfile.exists():
                squatter.append(http_server(port))
                return
            time.sleep(0.01)

    threading.Thread(target=squat, daemon=True).start()
    try:
        res = svc.run("start", "mlflow", PCPG_START_TIMEOUT="240", timeout=300)
    finally:
        stop.set()
        for server in squatter:
            server.shutdown()
            server.server_close()
    assert squatter, f"the squatter never saw {pidfile}:\n{res.stdout}{res.stderr}"
    out = f"rc={res.returncode}\n{res.stdout}{res.stderr}"
    assert res.returncode == 2, out
    assert "mlflow is up" not in res.stdout, out
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("services.sh: mlflow exited"), out
    assert f"port {port} (PCPG_MLFLOW_PORT) was taken" in lines[0], out
    svc.assert_nothing_left(keep_state=True)  # its log stays, for the reader


# ---------------------------------------------------------------------------- 2: PCPG_PG_URL
@pytest.mark.parametrize(
    "args",
    [("start", "mlflow"), ("start", "db"), ("start", "all"), ("env",)],
    ids=lambda a: "-".join(a),
)
@pytest.mark.parametrize(
    "url",
    [
        "postgresql://postgres@127.0.0.1:5432/test",
        "postgresql+psycopg2://postgres:pw@127.0.0.1:5432/test/",
    ],
    ids=["bare", "psycopg2-password"],
)
def test_pg_url_with_a_database_is_refused(svc, args, url):
    res = svc.run(*args, PCPG_PG_URL=url)
    line = svc.assert_refused(res, "PCPG_PG_URL", "server only", "PCPG_MLFLOW_DB", "PCPG_OPTUNA_DB")
    assert "pw" not in line  # the password is not echoed
    assert not res.stdout
    svc.assert_no_databases()


@pytest.mark.parametrize(
    "url",
    [
        "postgresql://postgres@127.0.0.1:5432",
        "postgresql+psycopg2://postgres@127.0.0.1:5432/",
        "postgresql+psycopg2://postgres:a/b@127.0.0.1:5432",
    ],
)
def test_pg_url_naming_the_server_is_accepted(svc, url):
    res = svc.run("env", PCPG_PG_URL=url)
    assert res.returncode == 0, res.stderr
    storage = re.search(r"--optuna-storage (\S+)", res.stdout).group(1)
    assert storage.startswith("postgresql+psycopg2://") and storage.endswith(":5432/" + svc.dbs[1])


def test_pg_url_options_follow_the_database(svc):
    """``?sslmode=...`` on the server URL: every database URL puts the database before it (the
    database was appended after the query), and ``start db`` connects with the option."""
    url = f"postgresql+psycopg2://{PG['user']}@{PG['host']}:{PG['port']}/?sslmode=disable"
    res = svc.run("env", PCPG_PG_URL=url)
    assert res.returncode == 0, res.stderr
    storage = re.search(r"--optuna-storage (\S+)", res.stdout).group(1)
    assert (
        storage
        == f"postgresql+psycopg2://{PG['user']}@{PG['host']}:{PG['port']}/{svc.dbs[1]}?sslmode=disable"
    )
    res = svc.run("start", "db", PCPG_PG_URL=url)
    assert res.returncode == 0, res.stderr
    assert all(db_exists(name) for name in svc.dbs)
    res = svc.run("start", "db", PCPG_PG_URL=url.replace("disable", "bogus"))
    assert res.returncode != 0 and "sslmode" in res.stderr, res.stderr  # the option reaches libpq


# ---------------------------------------------------------------------------- 3: Ray port
@pytest.mark.parametrize("what", ["ray", "all"])
def test_start_ray_refuses_port_in_use(svc, what):
    """`start all` refuses before it creates a database or starts MLflow."""
    port = int(svc.env["PCPG_RAY_PORT"])
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))
        s.listen()
        res = svc.run("start", what)
    svc.assert_refused(res, f"port {port}", "already in use", "PCPG_RAY_PORT")
    assert not res.stdout
    svc.assert_no_databases()


# ---------------------------------------------------------------------------- 4: join
def test_join_refuses_when_no_head_answers(svc):
    addr = f"127.0.0.1:{free_port()}"
    res = svc.run("join", addr)
    svc.assert_refused(res, f"no Ray head answers at {addr}")


@pytest.mark.parametrize("addr", ["127.0.0.1", "127.0.0.1:port", ":"])
def test_join_refuses_a_malformed_address(svc, addr):
    svc.assert_refused(svc.run("join", addr), "usage: services.sh join HEAD_IP:PORT")


def test_join_without_address_is_refused(svc):
    svc.assert_refused(svc.run("join"), "usage: services.sh join HEAD_IP:PORT")


# ---------------------------------------------------------------------------- 5: env and its docs
def test_env_variables_match_the_docs(svc):
    res = svc.run("env")
    assert res.returncode == 0, res.stderr
    names = re.findall(r"^export (\w+)=", res.stdout, flags=re.M)
    assert names == [
        "MLFLOW_TRACKING_URI",
        "RAY_ADDRESS",
        "RAY_AUTH_MODE",
        "RAY_ENABLE_UV_RUN_RUNTIME_ENV",
    ]
    readme = (ROOT / "ops" / "README.md").read_text()
    line = next(ln for ln in readme.splitlines() if 'eval "$(ops/services.sh env)"' in ln)
    for name in names:
        assert name in line, f"ops/README.md does not say `services.sh env` sets {name}: {line}"
    team = (ROOT / "docs" / "team-mode.md").read_text()
    block = team.split('eval "$(ops/services.sh env)"', 1)[1].split("```", 1)[0]
    for name in names:
        assert f"export {name}=" in block, f"docs/team-mode.md does not list {name}"


def test_unknown_service_is_refused(svc):
    svc.assert_refused(svc.run("start", "redis"), "unknown service 'redis'")
