"""Outputs of a real `pcpg run`: nothing the user writes is lost to the next run, and a run's
folders never read as valid when half-written."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from pcpg_dist.cli import main
from pcpg_dist.config import load_config
from pcpg_dist.runner import run_experiment

ROOT = Path(__file__).resolve().parent.parent

SMALL = {
    "name": "small", "seed": 0, "seeds": [0],
    "gridworld": {"layout_dir": str(ROOT / "experiments" / "gridworlds"), "environments": ["E1", "E3"]},
    "pbtg": {"episodes": 2000, "trajectories_per_style": 100, "dataset_per_style": 50},
    "clustering": {"k": 4, "pretrain_epochs": 2, "dec_epochs": 1},
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
def test_outputs_inside_the_folders_a_run_rewrites_are_refused(small_run, tmp_path, capsys, monkeypatch):
    """classify beside a run's cached data, export minari/onnx and report into cache/, summary/ or
    agents/ were written (exit 0) and deleted without a word by the next `pcpg run`."""
    run = copy_run(small_run, tmp_path)
    (data,) = (run / "cache" / "data").iterdir()
    model = next((run / "cache" / "cluster").iterdir()) / "model"
    before = listing(run)
    monkeypatch.chdir(data)  # classify's default --out: the current folder
    commands = [
        ["classify", str(model), str(data / "gridworld-E1.parquet")],
        ["classify", str(model), str(data / "gridworld-E1.parquet"), "--out", str(run / "summary" / "s.csv")],
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
    assert (tmp_path / "gridworld-E1.styles.csv").is_file() and (run / "onnx" / "agents_E3.onnx").is_file()
