"""Team mode against real services: `pcpg run` joins a `ray start --head` cluster and logs to an
`mlflow server` on PostgreSQL with proxied artifacts, all started by ops/services.sh.

The services are started and stopped here (never `ray stop`, which would end every Ray on the
machine: the launcher ends only the process groups it started). PostgreSQL itself must already
run on 127.0.0.1:5432 (user postgres, trust auth); a fresh database is created and dropped, so
reruns never see earlier runs. Without PostgreSQL the test is skipped, saying so.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
SERVICES = ROOT / "ops" / "services.sh"
PG = {"host": "127.0.0.1", "port": 5432, "user": "postgres", "dbname": "test"}
START_TIMEOUT = 420  # s; a loaded 2-core machine needed ~2 min for MLflow's first schema migration
RUN_TIMEOUT = 1200  # s; ~2-4 min measured on the shared 2-core machine

pytestmark = [pytest.mark.slow, pytest.mark.services]

TEAM = {
    "name": "team_tiny",
    "seed": 1,
    "seeds": [0, 1],
    "gridworld": {
        "layout_dir": str(ROOT / "pcpg_dist" / "data" / "gridworld"),
        "environments": ["E1", "E3"],
    },
    "pbtg": {"episodes": 20000, "trajectories_per_style": 200, "dataset_per_style": 100},
    "clustering": {
        "k": 4,
        "pretrain_epochs": 6,
        "dec_epochs": 3,
        "ceiling": False,
        "confidence_runs": 0,
    },
    "ranking": {"ps": [1.0, 0.5]},
    "bc": {"epochs": 300, "hidden_size": 16},
    "evaluation": {"rollouts_per_policy": 10, "corruption_levels": [0.0, 1.0], "figures": True},
}


def free_ports(n: int) -> list[int]:
    """``n`` distinct ports free on 127.0.0.1 right now (all bound at once, then released)."""
    socks = []
    try:
        for _ in range(n):
            s = socket.socket()
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def pg_admin():
    """An autocommit connection to the local PostgreSQL, or a skip saying why there is none."""
    psycopg2 = pytest.importorskip("psycopg2")
    try:
        conn = psycopg2.connect(connect_timeout=5, **PG)
    except psycopg2.OperationalError as e:
        pytest.skip(
            f"PostgreSQL is not reachable at {PG['host']}:{PG['port']} as {PG['user']} "
            f"(needed by the team-mode test): {str(e).strip().splitlines()[0]}"
        )
    conn.autocommit = True
    return conn


@pytest.fixture(scope="module")
def database():
    """A uniquely named, empty database for MLflow's backend store, dropped at the end."""
    conn = pg_admin()
    name = f"pcpg_test_{secrets.token_hex(4)}"
    try:
        yield name  # services.sh creates it (and would create it again on a rerun)
    finally:
        with conn.cursor() as cur:
            cur.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        conn.close()


def _kill_groups(state: Path) -> list[str]:
    """Last resort after `services.sh stop`: SIGKILL the process groups whose pid files remain."""
    left = []
    for pidfile in state.glob("*.pid"):
        pid = int(pidfile.read_text())
        try:
            os.killpg(pid, signal.SIGKILL)
            left.append(pidfile.stem)
        except (ProcessLookupError, PermissionError):
            pass
    return left


@pytest.fixture(scope="module")
def services(database, tmp_path_factory):
    """MLflow (PostgreSQL backend, proxied artifacts in tmp) and a 2-CPU Ray head on free ports."""
    base = tmp_path_factory.mktemp("team")
    # Ray's Unix socket paths must stay under ~107 characters: keep its temp dir short.
    ray_temp = tempfile.mkdtemp(prefix="pcpg-ray-")
    mlflow_port, ray_port, *extra = free_ports(8)
    ray_args = (
        "--num-cpus=2 --object-store-memory=200000000 --dashboard-port={} "
        "--dashboard-agent-listen-port={} --dashboard-agent-grpc-port={} --runtime-env-agent-port={} "
        "--metrics-export-port={} --node-manager-port={}"
    ).format(*extra)
    env = {
        **os.environ,
        "PCPG_BIN": str(Path(sys.executable).parent),
        "PCPG_SERVICES_DIR": str(base / "services"),
        "PCPG_PG_URL": f"postgresql+psycopg2://{PG['user']}@{PG['host']}:{PG['port']}",
        "PCPG_MLFLOW_DB": database,
        "PCPG_MLFLOW_PORT": str(mlflow_port),
        "PCPG_MLFLOW_WORKERS": "1",
        "PCPG_MLFLOW_ARTIFACTS": str(base / "artifacts"),
        "PCPG_RAY_PORT": str(ray_port),
        "PCPG_RAY_AUTH_MODE": "disabled",
        "PCPG_RAY_TEMP": ray_temp,
        "PCPG_RAY_ARGS": ray_args,
        "PCPG_START_TIMEOUT": str(START_TIMEOUT),
    }
    info = {
        "mlflow": f"http://127.0.0.1:{mlflow_port}",
        "ray": f"127.0.0.1:{ray_port}",
        "artifacts": base / "artifacts",
        "base": base,
    }
    try:
        # One after the other: MLflow's schema migration running beside it can make the raylet
        # miss Ray's fixed 30 s registration window on a busy 2-core machine.
        for what in ("ray", "mlflow"):
            res = subprocess.run(
                ["bash", str(SERVICES), "start", what],
                env=env,
                text=True,
                capture_output=True,
                timeout=3 * START_TIMEOUT,
            )
            assert res.returncode == 0, (
                f"services.sh start {what} failed:\n{res.stdout}{res.stderr}"
            )
        status = subprocess.run(
            ["bash", str(SERVICES), "status"], env=env, text=True, capture_output=True, timeout=60
        )
        assert status.returncode == 0, status.stdout + status.stderr
        yield info
    finally:
        subprocess.run(
            ["bash", str(SERVICES), "stop", "all"], env=env, timeout=180, capture_output=True
        )
        left = _kill_groups(base / "services")
        shutil.rmtree(ray_temp, ignore_errors=True)
        assert not left, f"services.sh stop left {left} running (killed now)"


@pytest.fixture(scope="module")
def team_run(services, tmp_path_factory):
    """`pcpg run` as its own process, joining the external cluster (this process never inits Ray)."""
    work = tmp_path_factory.mktemp("work")
    cfg = work / "team_tiny.yaml"
    cfg.write_text(yaml.safe_dump(TEAM))
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_ADDRESS", "MLFLOW_TRACKING_URI")}
    # The test cluster has token auth off; the driver must say so too. Ray's `uv run` hook would
    # ship the working dir and start the job's workers through `uv run`: pointless here, where the
    # `ray start` workers already run this venv with pcpg_dist installed.
    env.update(RAY_AUTH_MODE="disabled", RAY_ENABLE_UV_RUN_RUNTIME_ENV="0", PYTHONUNBUFFERED="1")
    cmd = [
        sys.executable,
        "-m",
        "pcpg_dist.cli",
        "run",
        str(cfg),
        "--workdir",
        str(work / "runs"),
        "--ray-address",
        services["ray"],
        "--tracking-uri",
        services["mlflow"],
        "--quiet",
    ]
    proc = subprocess.Popen(
        cmd, env=env, cwd=work, text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )
    try:
        out, _ = proc.communicate(timeout=RUN_TIMEOUT)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, f"pcpg run failed ({proc.returncode}):\n{out[-6000:]}"
    return {"out": work / "runs" / "team_tiny", "driver_pid": proc.pid, "output": out}


def test_driver_joined_the_external_cluster(services, team_run):
    """The cluster's own job table holds the finished `pcpg run` driver (no private local Ray)."""
    probe = (
        "import json, ray; ray.init(address='{}', log_to_driver=False); "
        "print(json.dumps([[j['DriverPid'], j['IsDead'], j['Entrypoint']] for j in ray._private.state.jobs()]))"
    )
    env = {**os.environ, "RAY_AUTH_MODE": "disabled", "RAY_ENABLE_UV_RUN_RUNTIME_ENV": "0"}
    res = subprocess.run(
        [sys.executable, "-c", probe.format(services["ray"])],
        env=env,
        text=True,
        capture_output=True,
        timeout=180,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    jobs = json.loads(res.stdout.strip().splitlines()[-1])
    mine = [j for j in jobs if j[0] == team_run["driver_pid"]]
    assert len(mine) == 1, jobs
    assert mine[0][1] is True and "pcpg_dist.cli run" in mine[0][2]


def test_runs_metrics_and_artifacts_on_the_server(services, team_run):
    from mlflow import MlflowClient

    client = MlflowClient(services["mlflow"])
    exp = client.get_experiment_by_name("team_tiny")
    assert exp.artifact_location.startswith("mlflow-artifacts:")  # proxied, not a client-side path
    runs = client.search_runs([exp.experiment_id])
    parents = [r for r in runs if r.data.tags.get("pcpg.role") == "parent"]
    assert len(parents) == 1 and parents[0].info.status == "FINISHED"
    parent = parents[0]
    children = {
        r.data.tags["pcpg.env"]: r
        for r in runs
        if r.data.tags.get("mlflow.parentRunId") == parent.info.run_id
    }
    assert sorted(children) == ["E1", "E3"] and len(runs) == 3
    assert all(c.info.status == "FINISHED" for c in children.values())

    # The parent's numbers are the run's summary, and they are real results, not placeholders;
    # laid out for review: the classic runs table, headline keys only, accuracy over p as a curve.
    assert exp.tags["mlflow.experimentKind"] == "custom_model_development"
    summary = json.loads((team_run["out"] / "summary" / "metrics.json").read_text())
    pm = parent.data.metrics
    assert len(pm) <= 30 and not any(
        k.endswith("/std") or k.startswith(("E1/", "E3/")) for k in pm
    ), sorted(pm)
    for key in ("pcpg/accuracy/p1", "baseline/accuracy/p1", "clustering/ari", "random/accuracy"):
        assert pm[key] == pytest.approx(summary[key]), key
    curve = {
        m.step: m.value for m in client.get_metric_history(parent.info.run_id, "accuracy_vs_p/pcpg")
    }
    assert curve == {
        100: pytest.approx(summary["pcpg/accuracy/p1"]),
        50: pytest.approx(summary["pcpg/accuracy/p0.5"]),
    }
    assert curve[50] > pm["random/accuracy"] + 0.2
    assert "pcpg run" in parent.data.tags["mlflow.note.content"]
    assert parent.data.params["bc.hidden_size"] == "16"
    for env, child in children.items():
        cm = child.data.metrics
        assert 0.3 < cm["clustering/ari"] <= 1.0, (env, cm["clustering/ari"])
        assert cm["pcpg/accuracy/p1"] > cm["random/accuracy"] + 0.2, env
        evaluation = {
            Path(a.path).name for a in client.list_artifacts(child.info.run_id, "evaluation")
        }
        assert "metrics.json" in evaluation and any(n.endswith(".png") for n in evaluation), (
            evaluation
        )
        assert "metrics.csv" in evaluation and "done.json" not in evaluation, (
            evaluation
        )  # std table, no bookkeeping
        assert client.list_artifacts(child.info.run_id, "models"), env

    # Artifacts went through the server into its artifacts dir, and come back byte for byte.
    top = {a.path for a in client.list_artifacts(parent.info.run_id)}
    assert {"summary", "report"} <= top
    report = {Path(a.path).name for a in client.list_artifacts(parent.info.run_id, "report")}
    assert {"report.html", "report.md"} <= report
    stored = (
        services["artifacts"]
        / exp.experiment_id
        / parent.info.run_id
        / "artifacts"
        / "summary"
        / "metrics.json"
    )
    assert json.loads(stored.read_text()) == summary
    fetched = client.download_artifacts(
        parent.info.run_id, "summary/metrics.json", str(services["base"] / "download")
    )
    assert Path(fetched).read_bytes() == (team_run["out"] / "summary" / "metrics.json").read_bytes()


def test_agents_model_loads_from_the_server(services, team_run):
    """The sweep's `agents` pyfunc model, fetched through the proxy, acts only on valid moves."""
    import mlflow
    import pandas as pd
    from mlflow import MlflowClient

    client = MlflowClient(services["mlflow"])
    exp = client.get_experiment_by_name("team_tiny")
    parent = client.search_runs([exp.experiment_id], filter_string="tags.`pcpg.role` = 'parent'")[0]
    before = mlflow.get_tracking_uri()
    mlflow.set_tracking_uri(services["mlflow"])
    try:
        agents = mlflow.pyfunc.load_model(f"runs:/{parent.info.run_id}/agents")
    finally:
        mlflow.set_tracking_uri(before)
    df = pd.DataFrame(
        {
            "env": ["E1", "E1", "E3", "E3"],
            "style": [0, 1, 2, 3],
            "p": [1.0, 0.5, 1.0, 0.5],
            "s0": [1] * 4,
            "s1": [1] * 4,
            "s2": [0] * 4,
            "s3": [0] * 4,
            "valid": [[False, True, True, False]] * 4,
        }
    )
    assert set(agents.predict(df)) <= {1, 2}  # right or down: the only valid actions in that corner
