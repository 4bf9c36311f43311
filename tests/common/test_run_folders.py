"""Outputs of a real `pcpg run`: nothing the user writes is lost to the next run, and a run's
folders never read as valid when half-written."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
import yaml

from pcpg_dist.api.run import run_experiment
from pcpg_dist.cli import main
from pcpg_dist.config import load_config

ROOT = Path(__file__).resolve().parents[2]

SMALL = {
    "name": "small",
    "seed": 0,
    "seeds": [0],
    "gridworld": {
        "layout_dir": str(ROOT / "pcpg_dist" / "data" / "gridworld"),
        "environments": ["E1", "E3"],
    },
    "pbtg": {"episodes": 2000, "trajectories_per_style": 100, "dataset_per_style": 50},
    "clustering": {
        "k": 4,
        "pretrain_epochs": 2,
        "dec_epochs": 1,
        "ceiling": False,
        "confidence_runs": 0,
    },
    "ranking": {"ps": [1.0, 0.5]},
    "bc": {"epochs": 20},
    "evaluation": {"rollouts_per_policy": 5, "corruption_levels": [0.0, 1.0], "figures": False},
}


def write_config(folder: Path, **changes) -> Path:
    path = folder / "small.yaml"
    path.write_text(yaml.safe_dump({**SMALL, **changes}))
    return path


@pytest.fixture(scope="module")
def small_run(ray_session, tmp_path_factory) -> Path:
    """A finished run folder (no tracking): ``WORKDIR/small`` with cache/, summary/, agents/, report/."""
    work = tmp_path_factory.mktemp("work")
    cfg = load_config(write_config(work))
    return run_experiment(cfg, workdir=work / "runs", track=False, show_progress=False).out_dir


def copy_run(run: Path, tmp_path: Path) -> Path:
    target = tmp_path / "runs" / run.name
    shutil.copytree(run, target)
    return target


def listing(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


@pytest.mark.slow
def test_outputs_inside_the_folders_a_run_rewrites_are_refused(
    small_run, tmp_path, capsys, monkeypatch
):
    """classify beside a run's cached data, export minari/onnx and report into cache/, summary/ or
    agents/ were written (exit 0) and deleted without a word by the next `pcpg run`."""
    run = copy_run(small_run, tmp_path)
    (data,) = (run / "cache" / "data").iterdir()
    model = next((run / "cache" / "cluster").iterdir()) / "model"
    before = listing(run)
    monkeypatch.chdir(data)  # classify's default --out: the current folder
    commands = [
        ["classify", str(model), str(data / "gridworld-E1.parquet")],
        [
            "classify",
            str(model),
            str(data / "gridworld-E1.parquet"),
            "--out",
            str(run / "summary" / "s.csv"),
        ],
        ["export", "minari", str(run), "--out", str(data)],
        ["export", "minari", str(run), "--out", str(run / "summary" / "minari")],
        ["export", "onnx", str(run), "--out", str(run / "agents" / "onnx")],
        ["report", str(run), "--out", str(run / "agents" / "report")],
        ["report", str(run), "--out", str(run / "cache")],
    ]
    for argv in commands:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "which the next `pcpg run`" in err[0], (argv, err)
    assert listing(run) == before
    # outside the rewritten folders, the same commands work
    monkeypatch.chdir(tmp_path)
    assert main(["classify", str(model), str(data / "gridworld-E1.parquet")]) == 0
    assert main(["export", "onnx", str(run), "--out", str(run / "onnx")]) == 0
    assert (tmp_path / "gridworld-E1.styles.csv").is_file() and (
        run / "onnx" / "agents_E3.onnx"
    ).is_file()


# `pcpg run` in a subprocess with Ray started first on 2 CPUs (as tests/test_faults.py does)
LAUNCH = (
    "import sys; from pcpg_dist.orchestration.ray_pool import init_ray; init_ray(num_cpus=2); "
    "from pcpg_dist.cli import main; sys.exit(main(sys.argv[1:]))"
)


def start_run(cfg: Path, workdir: Path, log: Path) -> subprocess.Popen:
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_ADDRESS", "MLFLOW_TRACKING_URI")}
    env.update(RAY_AUTH_MODE="disabled", RAY_ENABLE_UV_RUN_RUNTIME_ENV="0", PYTHONUNBUFFERED="1")
    return subprocess.Popen(
        [
            sys.executable,
            "-c",
            LAUNCH,
            "run",
            str(cfg),
            "--workdir",
            str(workdir),
            "--no-tracking",
            "--quiet",
        ],
        cwd=log.parent,
        env=env,
        stdout=log.open("w"),
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )


def kill_tree(proc: subprocess.Popen, sig: int = signal.SIGKILL) -> int:
    """Send ``sig`` to the driver, wait for it, then kill whatever of its Ray is left."""
    try:
        family = psutil.Process(proc.pid).children(recursive=True)
    except psutil.NoSuchProcess:
        family = []
    proc.send_signal(sig)
    code = proc.wait(timeout=60)
    for p in family:
        with contextlib.suppress(psutil.NoSuchProcess):
            p.kill()
    psutil.wait_procs(family, timeout=10)
    return code


@pytest.mark.slow
def test_a_rerun_killed_while_writing_its_summary_never_leaves_a_mixed_summary(
    small_run, tmp_path, capsys
):
    """A rerun with bc.epochs 30 SIGKILLed once its new metrics.json existed left the new metrics
    beside the old run.json (epochs 20), agents and report: `pcpg report` exited 0 with mixed
    numbers and `pcpg reproduce` blamed reproducibility."""
    run = copy_run(small_run, tmp_path)
    old_metrics = json.loads((run / "summary" / "metrics.json").read_text())
    cfg = write_config(tmp_path, bc={"epochs": 30})
    t0 = time.time()
    proc = start_run(cfg, tmp_path / "runs", tmp_path / "killed.log")

    def new_metrics() -> bool:
        return any(
            p.is_file() and p.stat().st_mtime > t0 for p in run.glob("*/summary/metrics.json")
        ) or any(p.is_file() and p.stat().st_mtime > t0 for p in run.glob("summary/metrics.json"))

    end = time.monotonic() + 400
    try:
        while not new_metrics() and proc.poll() is None and time.monotonic() < end:
            time.sleep(0.02)
    finally:
        code = kill_tree(proc)
    assert code == -signal.SIGKILL, (
        f"the run ended ({code}) before it was killed:\n{(tmp_path / 'killed.log').read_text()}"
    )

    if (run / "summary" / "run.json").exists():  # the old summary, whole
        info = json.loads((run / "summary" / "run.json").read_text())
        assert info["config"]["bc"]["epochs"] == 20
        assert json.loads((run / "summary" / "metrics.json").read_text()) == old_metrics
        assert main(["report", str(run), "--out", str(tmp_path / "rep")]) == 0
    else:  # no summary at all: one line, nothing mixed
        assert main(["report", str(run), "--out", str(tmp_path / "rep")]) == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1

    result = run_experiment(
        load_config(cfg), workdir=tmp_path / "runs", track=False, show_progress=False
    )
    info = json.loads((run / "summary" / "run.json").read_text())
    assert info["config"]["bc"]["epochs"] == 30 and result.metrics == json.loads(
        (run / "summary" / "metrics.json").read_text()
    )
    assert sorted(p.name for p in run.iterdir()) == [
        "agents",
        "cache",
        "cache.lock",
        "report",
        "summary",
    ]


@pytest.mark.slow
def test_sigterm_is_one_line_exit_143_and_marks_the_mlflow_run_killed(ray_session, tmp_path):
    """`kill PID` (or `timeout`) once Ray had started aborted with exit 134 and Ray's C++ stack dump
    (`*** SIGTERM received ...`), no `pcpg:` line, and left the MLflow parent RUNNING."""
    from mlflow import MlflowClient

    cfg, uri = write_config(tmp_path), f"sqlite:///{tmp_path / 'mlflow.db'}"
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_ADDRESS", "MLFLOW_TRACKING_URI")}
    env.update(RAY_AUTH_MODE="disabled", PYTHONUNBUFFERED="1")
    log = tmp_path / "run.log"
    MlflowClient(uri).search_experiments()  # the store's tables, made before two processes use it
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "pcpg_dist.cli",
            "run",
            str(cfg),
            "--workdir",
            str(tmp_path / "runs"),
            "--tracking-uri",
            uri,
            "--quiet",
        ],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=log.open("w"),
        start_new_session=True,
    )
    end = time.monotonic() + 400

    def parent_runs() -> list:
        if not list((tmp_path / "runs" / "small" / "cache" / "data").glob("*/done.json")):
            return []
        client = MlflowClient(uri)
        return client.search_runs([e.experiment_id for e in client.search_experiments()])

    try:  # Ray runs, the data is cached and the MLflow parent exists: Step A is under way
        while proc.poll() is None and time.monotonic() < end and not parent_runs():
            time.sleep(0.2)
    finally:
        code = kill_tree(proc, signal.SIGTERM)
    err = log.read_text().strip().splitlines()
    assert code == 143, (code, err[-12:])
    assert err == ["pcpg: interrupted (SIGTERM); rerun the same command to resume"], err[-12:]
    runs = parent_runs()
    assert [r.info.status for r in runs] == ["KILLED"]


@pytest.mark.slow
def test_agents_swapped_between_environments_are_refused_by_export(small_run, tmp_path, capsys):
    """E1's and E3's agents have the same sizes and carry no environment name: a group file copied
    from one environment over the other's used to export as the other's, exit 0. The run's
    agents/index.json (each file's SHA-256 per environment) finds it."""
    run = copy_run(small_run, tmp_path)
    assert (run / "agents" / "index.json").is_file()
    assert main(["export", "onnx", str(run), "--out", str(tmp_path / "ok")]) == 0
    capsys.readouterr()
    shutil.copyfile(run / "agents" / "E1" / "group000.pt", run / "agents" / "E3" / "group000.pt")
    assert main(["export", "onnx", str(run), "--out", str(tmp_path / "swapped")]) == 2
    err = capsys.readouterr().err.strip()
    assert "E3/group000.pt: not the file the run wrote here" in err and "\n" not in err
    assert not (tmp_path / "swapped").exists()


def test_the_names_written_beside_the_environments_are_all_reserved(small_run):
    """An environment may not be named like a file a run writes beside the environments' folders
    (run_folders.BESIDE_UNITS, checked before clustering): the list covers what a run writes."""
    from pcpg_dist.common.run_folders import BESIDE_UNITS

    envs = {"E1", "E3"}
    beside = {
        p.name for folder in ("summary", "agents", "report") for p in (small_run / folder).iterdir()
    }
    beside |= {p.name for p in small_run.iterdir()}
    assert envs <= beside  # the environments' folders are there, beside the rest
    assert beside - envs - {"cache.lock"} <= BESIDE_UNITS, beside - envs - BESIDE_UNITS
