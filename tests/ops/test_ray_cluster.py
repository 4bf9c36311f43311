"""A real two-node Ray cluster on this machine, with no shared disk between driver and workers.

The head node has 0 CPUs, so every task runs on the worker node. That node runs in its own mount
namespace (``unshare -m``) with tmpfs mounted over the driver's working folder, the package source
and the experiments folder: a task that read a path on the driver's disk, or imported the package
from it instead of from what the driver ships, would fail. `pcpg run --ray-address` must finish
there with the same metrics as an embedded run; a plain `pcpg run` beside the running cluster
must start its own private Ray; `ray job submit -- pcpg run ...` must work; an impossible CPU
request must fail in one line.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
pytestmark = [pytest.mark.slow, pytest.mark.services]

TINY = {
    "name": "nodisk",
    "seed": 3,
    "seeds": [0, 1],
    "gridworld": {"layout_dir": "layouts", "environments": ["E1", "E2"]},
    "pbtg": {"episodes": 20000, "trajectories_per_style": 200, "dataset_per_style": 100},
    "clustering": {"k": 4, "method": "bag_auto", "ceiling": False, "confidence_runs": 0},
    "ranking": {"ps": [1.0, 0.5]},
    "bc": {"epochs": 200, "hidden_size": 16},
    "evaluation": {"rollouts_per_policy": 10, "corruption_levels": [0.0, 1.0], "figures": True},
    "runner": {"cpus_per_task": 1},
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def clean_env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_ADDRESS", "MLFLOW_TRACKING_URI")}
    env["PATH"] = f"{BIN}{os.pathsep}{env.get('PATH', '')}"
    # a loaded machine can take more than Ray's default to start a node's agents
    env.setdefault("RAY_raylet_start_wait_time_s", "300")
    env.update(extra)
    return env


def wait_for_cpus(address: str, cpus: float, timeout: float = 240) -> None:
    assert cpus_reached(address, cpus, timeout), f"the cluster at {address} never had {cpus} CPUs"


def cpus_reached(address: str, cpus: float, timeout: float) -> bool:
    probe = (
        f"import ray, time; ray.init(address={address!r}, logging_level='ERROR'); t = time.time()\n"
        f"while ray.cluster_resources().get('CPU', 0) < {cpus} and time.time() - t < {timeout}: time.sleep(1)\n"
        f"print(ray.cluster_resources().get('CPU', 0))"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe],
        env=clean_env(),
        capture_output=True,
        text=True,
        timeout=timeout + 60,
    )
    lines = out.stdout.strip().splitlines()
    return out.returncode == 0 and bool(lines) and float(lines[-1]) >= cpus


def stop(proc: subprocess.Popen) -> None:
    """Stop one `ray start --block` and everything it started (never `ray stop`: it would kill
    every Ray on the machine, the test session's own included)."""
    try:
        family = [psutil.Process(proc.pid), *psutil.Process(proc.pid).children(recursive=True)]
    except psutil.NoSuchProcess:
        family = []
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=15)
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)
    for p in family:
        with contextlib.suppress(psutil.Error):
            p.kill()
    proc.wait()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    if os.geteuid() != 0 or not shutil.which("unshare"):
        pytest.skip("needs root and unshare(1) for a worker node in a private mount namespace")
    drv = tmp_path_factory.mktemp("driver")
    (drv / "layouts").mkdir()
    for env in ("E1", "E2"):
        shutil.copyfile(
            ROOT / "pcpg_dist" / "data" / "gridworld" / f"{env}.txt", drv / "layouts" / f"{env}.txt"
        )
    (drv / "tiny.yaml").write_text(yaml.safe_dump(TINY))
    port, dash = free_port(), free_port()
    # Each node's agent on its own free port: both nodes share this machine, and Ray's fixed default
    # (52365) may be held by anything else on it; a head whose agent cannot bind its port refuses
    # every job submission.
    agent_ports = [f"--dashboard-agent-listen-port={free_port()}" for _ in range(2)]
    logs = drv.parent / f"{drv.name}-logs"
    logs.mkdir()
    head = subprocess.Popen(
        [
            str(BIN / "ray"),
            "start",
            "--head",
            "--block",
            "--num-cpus=0",
            "--node-ip-address=127.0.0.1",
            f"--port={port}",
            "--include-dashboard=true",
            "--dashboard-host=127.0.0.1",
            f"--dashboard-port={dash}",
            "--disable-usage-stats",
            agent_ports[0],
        ],
        env=clean_env(),
        stdout=(logs / "head.log").open("w"),  # noqa: SIM115 - open for the node's life
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    hidden = [drv, ROOT / "pcpg_dist", ROOT / "experiments"]
    mounts = " && ".join(f"mount -t tmpfs tmpfs '{d}'" for d in hidden)
    worker_cmd = (
        f"{mounts} && exec '{BIN / 'ray'}' start --block --address=127.0.0.1:{port} --num-cpus=2 --num-gpus=1 "
        f"--node-ip-address=127.0.0.1 --disable-usage-stats {agent_ports[1]}"
    )
    worker = None
    try:
        wait_for_cpus(f"127.0.0.1:{port}", 0)
        # A node's agents can miss Ray's start-up window on a busy machine: try the worker thrice.
        for attempt in range(3):
            worker = subprocess.Popen(
                ["unshare", "-m", "--propagation", "private", "sh", "-c", worker_cmd],
                env=clean_env(),
                stdout=(logs / f"worker{attempt}.log").open("w"),  # noqa: SIM115
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
            if cpus_reached(f"127.0.0.1:{port}", 2, timeout=150):
                break
            stop(worker)
            worker = None
        assert worker is not None, f"the worker node did not join; see {logs}"
        yield {"address": f"127.0.0.1:{port}", "dashboard": f"http://127.0.0.1:{dash}", "drv": drv}
    finally:
        if worker is not None:
            stop(worker)
        stop(head)


def pcpg(args: list[str], cwd: Path, timeout: float = 900) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(BIN / "pcpg"), *args],
        cwd=cwd,
        env=clean_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def results(folder: Path) -> dict[str, float]:
    m = json.loads((folder / "summary" / "metrics.json").read_text())
    return {k: v for k, v in m.items() if "seconds" not in k}


def test_no_shared_disk_run_equals_embedded_run(cluster):
    drv = cluster["drv"]
    # As a user would from outside the project: `uv run --project` (Ray's uv hook must not break it)
    uv = shutil.which("uv")
    prefix = [uv, "run", "--project", str(ROOT), "--frozen", "pcpg"] if uv else [str(BIN / "pcpg")]
    remote = subprocess.run(
        [
            *prefix,
            "run",
            "tiny.yaml",
            "--no-tracking",
            "--quiet",
            "--workdir",
            "remote",
            "--ray-address",
            cluster["address"],
        ],
        cwd=drv,
        env=clean_env(),
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert remote.returncode == 0, remote.stderr[-3000:]
    # Beside a running `ray start` cluster, no address means a private local Ray (not "num_cpus
    # must not be provided" from joining that cluster by accident).
    local = pcpg(["run", "tiny.yaml", "--no-tracking", "--quiet", "--workdir", "local"], drv)
    assert local.returncode == 0, local.stderr[-3000:]
    a, b = results(drv / "remote" / "nodisk"), results(drv / "local" / "nodisk")
    assert a.keys() == b.keys() and len(a) > 50
    assert a == b
    assert a["clustering/accuracy"] > 0.6


def test_impossible_cpu_request_fails_in_one_line(cluster):
    t0 = time.monotonic()
    out = pcpg(
        [
            "run",
            "tiny.yaml",
            "--no-tracking",
            "--quiet",
            "--workdir",
            "big",
            "runner.cpus_per_task=64",
            "--ray-address",
            cluster["address"],
        ],
        cluster["drv"],
        timeout=300,
    )
    assert out.returncode == 2
    lines = [ln for ln in out.stderr.splitlines() if ln.startswith("pcpg: error")]
    assert len(lines) == 1 and "runner.cpus_per_task" in lines[0] and "at most 2" in lines[0], (
        out.stderr[-2000:]
    )
    assert time.monotonic() - t0 < 240
    assert not (cluster["drv"] / "big" / "nodisk" / "cache" / "cluster").exists()


def test_stages_on_a_gpu_ask_ray_for_one(cluster):
    """The worker node declares one GPU (a Ray resource: this machine has none that torch sees).
    With ``device: auto`` the driver sees a GPU in the cluster, so Step A's and Step C's tasks ask
    Ray for ``runner.gpus_per_task`` of it (Ray's own record of the tasks says so); inside them
    torch finds no GPU, so they train on the CPU and the run finishes. A stage on ``cpu`` asks
    for none."""
    out = pcpg(
        [
            "run",
            "tiny.yaml",
            "--no-tracking",
            "--quiet",
            "--workdir",
            "gpu",
            "clustering.method=lstm_dec",
            "clustering.pretrain_epochs=2",
            "clustering.dec_epochs=1",
            "clustering.device=auto",
            "bc.device=auto",
            "runner.gpus_per_task=0.5",
            "--ray-address",
            cluster["address"],
        ],
        cluster["drv"],
    )
    assert out.returncode == 0, out.stderr[-3000:]
    listed = subprocess.run(
        [
            str(BIN / "ray"),
            "list",
            "tasks",
            "--address",
            cluster["dashboard"],
            "--detail",
            "--format",
            "json",
            "--limit",
            "10000",
        ],
        env=clean_env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert listed.returncode == 0, listed.stderr[-2000:]
    asked = {}
    for task in json.loads(listed.stdout):
        name = task.get("func_or_class_name", "")
        asked.setdefault(name.rsplit(".", 1)[-1], set()).add(
            (task.get("required_resources") or {}).get("GPU", 0.0)
        )
    assert 0.5 in asked.get("cluster_task", set()) and 0.5 in asked.get("train_task", set()), asked
    assert asked.get("evaluate_task") == {0.0}, asked  # evaluation runs on the CPU


def test_ray_job_submit(cluster, tmp_path):
    """`ray job submit -- pcpg run ...` from a folder outside the project, no extra variables."""
    cfg = cluster["drv"] / "tiny.yaml"
    out_dir = tmp_path / "job-out"
    entry = [
        "pcpg",
        "run",
        str(cfg),
        "--no-tracking",
        "--quiet",
        "--workdir",
        str(out_dir),
        "bc.epochs=100",
    ]
    job = subprocess.run(
        [str(BIN / "ray"), "job", "submit", "--address", cluster["dashboard"], "--", *entry],
        cwd=tmp_path,
        env=clean_env(),
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert job.returncode == 0, (job.stdout + job.stderr)[-3000:]
    assert "succeeded" in (job.stdout + job.stderr).lower()
    m = results(out_dir / "nodisk")
    assert m["clustering/accuracy"] > 0.6


def test_the_drivers_openmp_wait_policy_reaches_the_clusters_workers(cluster, tmp_path):
    """A `ray start` node's workers do not inherit the driver's environment (this cluster's nodes
    were started with the suite's PASSIVE): the OpenMP wait policy a user sets for a run reaches
    its tasks on the cluster all the same, beside the one-thread defaults."""
    keys = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "OMP_NUM_THREADS")
    probe = (
        "import json, os, ray\n"
        "from pcpg_dist.orchestration.ray_pool import init_ray\n"
        f"init_ray({cluster['address']!r})\n"
        f"env = ray.remote(lambda: {{k: os.environ.get(k) for k in {keys!r}}})\n"
        "print(json.dumps(ray.get(env.remote())))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe],
        cwd=tmp_path,
        env=clean_env(OMP_WAIT_POLICY="ACTIVE", GOMP_SPINCOUNT="12345"),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    seen = json.loads(out.stdout.strip().splitlines()[-1])
    assert seen == {"OMP_WAIT_POLICY": "ACTIVE", "GOMP_SPINCOUNT": "12345", "OMP_NUM_THREADS": "1"}


def test_private_ray_listens_on_loopback_only(cluster, tmp_path):
    """The embedded Ray (no address) is reachable from this machine only."""
    probe = (
        "import os, psutil, ray\n"
        "from pcpg_dist.orchestration.ray_pool import init_ray\n"
        "init_ray(num_cpus=1)\n"
        "pid = psutil.Process()\n"
        "procs = [pid, *pid.children(recursive=True)]\n"
        "node = ray.get_runtime_context().get_node_id()\n"
        "addrs = set()\n"
        "for p in psutil.process_iter(['pid', 'cmdline']):\n"
        "    cmd = ' '.join(p.info['cmdline'] or [])\n"
        "    if ray._private.worker.global_worker.node.get_session_dir_path() in cmd or p.pid == os.getpid():\n"
        "        procs.append(p)\n"
        "for p in procs:\n"
        "    try:\n"
        "        addrs |= {c.laddr.ip for c in p.net_connections('tcp') if c.status == 'LISTEN'}\n"
        "    except psutil.Error:\n"
        "        pass\n"
        "import json; print(json.dumps(sorted(addrs)))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe],
        cwd=tmp_path,
        env=clean_env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    addrs = json.loads(out.stdout.strip().splitlines()[-1])
    assert addrs, "found no listening sockets of the private Ray"
    assert all(a in ("127.0.0.1", "::ffff:127.0.0.1", "::1") for a in addrs), addrs


def test_a_streamed_log_runs_over_both_nodes_with_no_shared_disk(cluster):
    """The log lies on the driver's disk only: its blocks are read on the driver's node, every
    later step (aggregation, k-means passes, the BC groups) runs on the worker node, and the
    numbers equal a private embedded run's."""
    from ray.util.state import list_nodes, list_tasks

    from pcpg_dist.domains.trajectories.synthetic_log import write_styled_log

    drv = cluster["drv"]
    # PCPG_NODES_TRAJECTORIES=1000000 makes this the million-trajectory run of docs/scale.md
    n = int(os.environ.get("PCPG_NODES_TRAJECTORIES", "600"))
    write_styled_log(drv / "big.parquet", n, d=8 if n <= 10_000 else 32, seed=2)
    cfg = {
        "name": "streamed",
        "domain": "trajectories",
        "seeds": [0],
        "trajectories": {"path": "big.parquet", "stream": "on"},
        "clustering": {"k": 4, "ceiling": False, "confidence_runs": 0},
        "ranking": {"ps": [1.0, 0.5]},
    }
    (drv / "streamed.yaml").write_text(yaml.safe_dump(cfg))
    remote = pcpg(
        ["run", "streamed.yaml", "--no-tracking", "--quiet", "--workdir", "sremote",
         "--ray-address", cluster["address"]],
        drv,
    )  # fmt: skip
    assert remote.returncode == 0, remote.stderr[-3000:]
    local = pcpg(["run", "streamed.yaml", "--no-tracking", "--quiet", "--workdir", "slocal"], drv)
    assert local.returncode == 0, local.stderr[-3000:]
    a, b = (
        json.loads((drv / w / "streamed" / "summary" / "streamed.json").read_text())
        for w in ("sremote", "slocal")
    )
    assert a["clustering"] == b["clustering"] and a["clustering"]["clustering/accuracy"] > 0.95
    # the accuracies within a point: the two clusters cut the log into other blocks, so the BC
    # cells see their rows in another order (and may stop at another epoch)
    for key, value in b["metrics"].items():
        if "accuracy" in key:
            assert a["metrics"][key] == pytest.approx(value, abs=0.01), key
    head = next(n.node_id for n in list_nodes(address=cluster["dashboard"]) if n.is_head_node)
    tasks = list_tasks(address=cluster["dashboard"], limit=10_000, raise_on_missing_output=False)
    where = {}
    for t in tasks:
        where.setdefault(t.name, set()).add("head" if t.node_id == head else "worker")
    reads = {w for name, nodes in where.items() if "MapBatches(read)" in name for w in nodes}
    assert reads == {"head"}, sorted(where.items())
    print(
        json.dumps({"trajectories": n, "remote": a["stage_seconds"], "local": b["stage_seconds"]})
    )
    print(json.dumps({name: sorted(nodes) for name, nodes in sorted(where.items())}))
    assert where.get("train_group") == {"worker"}, sorted(where.items())
    aggregated = {w for name, nodes in where.items() if "Aggregate" in name for w in nodes}
    assert "worker" in aggregated, sorted(where.items())
