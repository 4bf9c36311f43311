"""The deployment files a team copies (ops/deploy/): parsed and checked here, and the part
this machine can run for real (the compose file's `mlflow server` command line on PostgreSQL)
run for real.

Neither Docker nor Kubernetes runs on the test machine, so the Dockerfile, the KubeRay manifests
and the compose file are checked for what breaks them in practice: versions that drift from
uv.lock, a head that would take tasks, a PostgreSQL URI without the psycopg2 driver, artifacts
that are not proxied, an install that ignores the lock. The cluster-launcher YAML is validated
against the locked Ray's own schema.
"""

from __future__ import annotations

import copy
import os
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "ops" / "deploy"
MANIFESTS = sorted(DEPLOY.glob("*.yaml"))
PG = {"host": "127.0.0.1", "port": 5432, "user": "postgres", "dbname": "test"}
START_TIMEOUT = 420  # s; MLflow's first schema migration took ~2 min on the loaded 2-core machine


def locked_version(name: str) -> str:
    lock = tomllib.loads((ROOT / "uv.lock").read_text())
    (version,) = [p["version"] for p in lock["package"] if p["name"] == name]
    return version


def docs(name: str) -> list[dict]:
    return [d for d in yaml.safe_load_all((DEPLOY / name).read_text()) if d is not None]


def one(name: str, kind: str) -> dict:
    (doc,) = [d for d in docs(name) if d.get("kind") == kind]
    return doc


def containers(pod_template: dict) -> list[dict]:
    return pod_template["spec"]["containers"]


def compose_mlflow() -> dict:
    return docs("docker-compose.yaml")[0]["services"]["mlflow"]


def k8s_mlflow() -> dict:
    (c,) = containers(one("mlflow-k8s.yaml", "Deployment")["spec"]["template"])
    return c


def flag(argv: list[str], name: str) -> str:
    return argv[argv.index(name) + 1]


def test_every_manifest_parses_and_names_what_it_is():
    assert {p.name for p in MANIFESTS} >= {
        "raycluster.yaml",
        "rayjob.yaml",
        "docker-compose.yaml",
        "mlflow-k8s.yaml",
        "ray-cluster-launcher.yaml",
    }
    for path in MANIFESTS:
        loaded = docs(path.name)
        assert loaded, path
        if path.name in ("docker-compose.yaml", "ray-cluster-launcher.yaml"):
            continue
        for d in loaded:  # Kubernetes objects
            assert {"apiVersion", "kind", "metadata"} <= set(d), (path.name, d.keys())
            assert re.fullmatch(r"[a-z0-9]([-a-z0-9]*[a-z0-9])?", d["metadata"]["name"]), path.name
    kinds = {
        (d["apiVersion"], d["kind"])
        for p in ("raycluster.yaml", "rayjob.yaml", "mlflow-k8s.yaml")
        for d in docs(p)
    }
    assert kinds == {
        ("ray.io/v1", "RayCluster"),
        ("ray.io/v1", "RayJob"),
        ("v1", "Service"),
        ("apps/v1", "StatefulSet"),
        ("apps/v1", "Deployment"),
        ("v1", "PersistentVolumeClaim"),
    }


def test_raycluster_head_takes_no_tasks_and_pins_the_locked_ray():
    spec = one("raycluster.yaml", "RayCluster")["spec"]
    assert spec["rayVersion"] == locked_version("ray")
    assert spec["authOptions"]["mode"] == "token"
    head = spec["headGroupSpec"]
    assert head["rayStartParams"]["num-cpus"] == "0"
    groups = spec["workerGroupSpecs"]
    assert groups and len({g["groupName"] for g in groups}) == len(groups)
    for g in groups:
        assert g["minReplicas"] <= g["replicas"] <= g["maxReplicas"], g["groupName"]
    images = set()
    for group in [head, *groups]:
        # KubeRay passes rayStartParams to `ray start` and its CRD allows strings only.
        assert all(isinstance(v, str) for v in group["rayStartParams"].values()), group[
            "rayStartParams"
        ]
        for c in containers(group["template"]):
            images.add(c["image"])
            for part in ("requests", "limits"):
                assert {"cpu", "memory"} <= set(c["resources"][part]), (c["name"], part)
            assert any(m["mountPath"] == "/dev/shm" for m in c["volumeMounts"]), c["name"]
    assert len(images) == 1  # head and workers run the one image built from uv.lock
    (head_c,) = containers(head["template"])
    tracking = {e["name"]: e.get("value") for e in head_c["env"]}["MLFLOW_TRACKING_URI"]
    names = {d["metadata"]["name"]: d for d in docs("mlflow-k8s.yaml") if d["kind"] == "Service"}
    assert tracking == f"http://pcpg-mlflow:{names['pcpg-mlflow']['spec']['ports'][0]['port']}"


def test_rayjob_runs_pcpg_on_the_same_cluster_shape():
    job = one("rayjob.yaml", "RayJob")["spec"]
    assert job["rayClusterSpec"] == one("raycluster.yaml", "RayCluster")["spec"]
    assert job["entrypoint"].startswith("pcpg run /app/experiments/")
    config = job["entrypoint"].split()[2].removeprefix("/app/")
    assert (ROOT / config).is_file()  # the Dockerfile copies experiments/ to /app/experiments
    assert job["shutdownAfterJobFinishes"] is True


def test_dockerfile_installs_from_the_lock_at_the_locked_versions():
    text = (DEPLOY / "Dockerfile").read_text()
    instructions = text.replace("\\\n", " ").splitlines()  # one line per instruction
    runs = [line for line in instructions if line.startswith("RUN ")]
    syncs = [m for line in runs for m in re.findall(r"uv sync ([^&]*)", line)]
    assert len(syncs) == 2 and all("--locked" in s and "--extra cluster" in s for s in syncs), syncs
    assert "pip install" not in text  # nothing installed around the lock
    args = dict(re.findall(r"^ARG (\w+)=(\S+)", text, flags=re.M))
    assert args["RAY_VERSION"] == locked_version("ray")
    assert args["MLFLOW_VERSION"] == locked_version("mlflow")
    # The 'cluster' extra brings ray[default]: the dashboard, job server and dashboard agent that
    # `ray job submit` and KubeRay's health probes talk to.
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert any(d.startswith("ray[default]") for d in project["optional-dependencies"]["cluster"])
    for src in re.findall(r"^COPY (?!--from)(.+) \S+$", text, flags=re.M):
        for path in src.split():
            assert (ROOT / path).exists(), path
    ignore = (DEPLOY / "Dockerfile.dockerignore").read_text().split()
    assert "**" in ignore and "!uv.lock" in ignore  # the multi-GB .venv stays out of the context


def test_uv_lock_is_current_so_sync_locked_succeeds():
    uv = shutil.which("uv")
    if uv is None:
        pytest.skip("uv is not on PATH")
    res = subprocess.run(
        [uv, "lock", "--check", "--offline"], cwd=ROOT, text=True, capture_output=True, timeout=120
    )
    assert res.returncode == 0, res.stderr[-2000:]


@pytest.mark.parametrize("server", [compose_mlflow, k8s_mlflow], ids=["compose", "kubernetes"])
def test_mlflow_server_uses_postgresql_and_proxies_artifacts(server):
    svc = server()
    argv = svc["command"]
    assert argv[:2] == ["mlflow", "server"]
    assert flag(argv, "--backend-store-uri").startswith("postgresql+psycopg2://")
    assert "--serve-artifacts" in argv and flag(argv, "--artifacts-destination") == "/mlartifacts"
    assert "--default-artifact-root" not in argv and "--no-serve-artifacts" not in argv
    # Artifacts on a volume, not in the container's own layer.
    mounts = (
        [v.split(":")[1] for v in svc["volumes"]]
        if "volumes" in svc
        else [m["mountPath"] for m in svc["volumeMounts"]]
    )
    assert "/mlartifacts" in mounts
    # The password comes from PGPASSWORD (a secret), never from the URI in the process list.
    user = flag(argv, "--backend-store-uri").split("//", 1)[1].split("@", 1)[0]
    assert user == "mlflow", user
    env = (
        svc["environment"]
        if isinstance(svc.get("environment"), dict)
        else {e["name"]: e for e in svc["env"]}
    )
    assert "PGPASSWORD" in env


def test_compose_and_kubernetes_run_the_same_server():
    a, b = compose_mlflow()["command"], k8s_mlflow()["command"]
    host = re.compile(r"@[^:/]+")
    assert [host.sub("@HOST", x) for x in a] == [host.sub("@HOST", x) for x in b]
    assert compose_mlflow()["build"]["dockerfile"] == "ops/deploy/Dockerfile"
    assert (DEPLOY / compose_mlflow()["build"]["context"] / "uv.lock").resolve() == ROOT / "uv.lock"


def test_cluster_launcher_yaml_passes_the_locked_rays_schema():
    from ray.autoscaler._private.util import prepare_config, validate_config

    raw = docs("ray-cluster-launcher.yaml")[0]
    validate_config(prepare_config(copy.deepcopy(raw)))
    assert any("--num-cpus=0" in c for c in raw["head_start_ray_commands"] if "ray start" in c)
    assert (
        raw["docker"]["image"]
        == containers(one("raycluster.yaml", "RayCluster")["spec"]["headGroupSpec"]["template"])[0][
            "image"
        ]
    )
    broken = copy.deepcopy(raw)
    broken["docker"]["imagee"] = broken["docker"]["image"]  # the schema does catch a typo
    with pytest.raises(Exception, match="imagee"):
        validate_config(prepare_config(broken))


# --------------------------------------------------------------------------- the server, for real
def interpolate(value: str, given: dict[str, str]) -> str:
    """Compose's ``${VAR}``, ``${VAR:-default}``, ``${VAR:?error}``: ``given`` first, then default."""

    def sub(m: re.Match) -> str:
        name, op, rest = m.group(1), m.group(2), m.group(3)
        if name in given:
            return given[name]
        if op == ":-":
            return rest
        raise KeyError(f"{name} must be given ({rest})")

    return re.sub(r"\$\{(\w+)(?:(:[-?])([^}]*))?\}", sub, value)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def pg_database():
    psycopg2 = pytest.importorskip("psycopg2")
    try:
        conn = psycopg2.connect(connect_timeout=5, **PG)
    except psycopg2.OperationalError as e:
        pytest.skip(
            f"PostgreSQL is not reachable at {PG['host']}:{PG['port']}: {str(e).strip()[:200]}"
        )
    conn.autocommit = True
    name = f"pcpg_deploy_{secrets.token_hex(4)}"
    with conn.cursor() as cur:
        cur.execute(f'CREATE DATABASE "{name}"')
    try:
        yield name
    finally:
        with conn.cursor() as cur:
            cur.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        conn.close()


@pytest.mark.slow
@pytest.mark.services
def test_compose_server_command_logs_and_serves_artifacts(pg_database, tmp_path):
    """The compose file's `mlflow server` line and environment, with only the addresses swapped
    for this machine's: a run logged through it reads back, its artifact lands in the server's
    artifacts folder, and the Host guard admits the compose service name and nothing else."""
    import requests
    from mlflow import MlflowClient

    svc = compose_mlflow()
    argv = list(svc["command"])
    assert flag(argv, "--backend-store-uri").startswith("postgresql+psycopg2://")
    port = free_port()
    swaps = {
        "--backend-store-uri": f"postgresql+psycopg2://{PG['user']}@{PG['host']}:{PG['port']}/{pg_database}",
        "--artifacts-destination": str(tmp_path / "mlartifacts"),
        "--host": "127.0.0.1",
        "--port": str(port),
    }
    for name, value in swaps.items():
        argv[argv.index(name) + 1] = value
    argv[0] = str(Path(sys.executable).parent / "mlflow")
    env = {k: v for k, v in os.environ.items() if not k.startswith("MLFLOW_")}
    env.update(
        {
            k: interpolate(str(v), {"PCPG_PG_PASSWORD": "unused-with-trust-auth"})
            for k, v in svc["environment"].items()
        }
    )
    log = (tmp_path / "server.log").open("w")
    proc = subprocess.Popen(
        argv, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True
    )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + START_TIMEOUT
        while True:
            assert proc.poll() is None, (tmp_path / "server.log").read_text()[-3000:]
            try:
                if requests.get(f"{url}/health", timeout=5).status_code == 200:
                    break
            except requests.ConnectionError:
                pass
            assert time.monotonic() < deadline, "mlflow server did not answer /health in time"
            time.sleep(2)

        client = MlflowClient(url)
        exp_id = client.create_experiment("deploy_check")
        assert client.get_experiment(exp_id).artifact_location.startswith("mlflow-artifacts:")
        run = client.create_run(exp_id)
        client.log_metric(run.info.run_id, "accuracy", 0.875, step=3)
        table = tmp_path / "table.csv"
        table.write_text("style,accuracy\n0,0.875\n")
        client.log_artifact(run.info.run_id, str(table), "evaluation")
        client.set_terminated(run.info.run_id)

        back = client.get_run(run.info.run_id)
        assert back.data.metrics == {"accuracy": 0.875} and back.info.status == "FINISHED"
        stored = (
            tmp_path
            / "mlartifacts"
            / exp_id
            / run.info.run_id
            / "artifacts"
            / "evaluation"
            / "table.csv"
        )
        assert stored.read_text() == table.read_text()  # written by the server, not by the client
        fetched = client.download_artifacts(
            run.info.run_id, "evaluation/table.csv", str(tmp_path / "dl")
        )
        assert Path(fetched).read_bytes() == table.read_bytes()

        api = f"{url}/api/2.0/mlflow/experiments/get?experiment_id={exp_id}"
        assert requests.get(api, headers={"Host": "mlflow:5000"}, timeout=10).status_code == 200
        assert (
            requests.get(api, headers={"Host": "evil.example:5000"}, timeout=10).status_code == 403
        )
    finally:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=30)
        except ProcessLookupError:
            pass
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        log.close()
