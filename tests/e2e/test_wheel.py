"""pcpg as a user installs it: the wheel built from this checkout, installed into a fresh venv
(with the locked versions of its dependencies, none of the dev tools), run on a tiny config from
an empty folder that holds no repository file. Checked: the outputs, and that every command it
prints for the user fits that install (plain ``mlflow ui``, never ``uv run``)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from mini_config import mini_yaml

ROOT = Path(__file__).resolve().parents[2]
MINI = mini_yaml()

pytestmark = pytest.mark.slow


def uv() -> str:
    found = os.environ.get("UV") or shutil.which("uv")
    if not found:
        pytest.skip("uv is not installed (CI installs it: .ci/run)")
    return found


@pytest.fixture(scope="module")
def venv(tmp_path_factory) -> Path:
    """A fresh venv with the wheel and the locked runtime dependencies (uv's cache: no download)."""
    tmp = tmp_path_factory.mktemp("wheel")
    run = {"check": True, "capture_output": True, "text": True, "cwd": ROOT}
    subprocess.run([uv(), "build", "--wheel", "--out-dir", str(tmp / "dist")], **run)
    (wheel,) = (tmp / "dist").glob("pcpg_dist-*.whl")
    req = tmp / "requirements.txt"
    export = ["export", "--frozen", "--no-dev", "--no-hashes", "--no-emit-project", "-o", str(req)]
    subprocess.run([uv(), *export], **run)
    subprocess.run([uv(), "venv", "-q", str(tmp / "venv"), "--python", sys.executable], **run)
    python = tmp / "venv" / "bin" / "python"
    install = ["pip", "install", "-q", "--python", str(python), "-r", str(req), str(wheel)]
    subprocess.run([uv(), *install], **run)
    return tmp / "venv"


def test_the_installed_wheel_runs_a_tiny_config_from_an_empty_folder(venv, tmp_path):
    (tmp_path / "mini.yaml").write_text(MINI)
    # a shell with the venv activated, not under uv; no repository file within reach
    env = {k: v for k, v in os.environ.items() if k not in ("UV", "VIRTUAL_ENV", "PYTHONPATH")}
    env.update(PATH=f"{venv / 'bin'}{os.pathsep}/usr/bin:/bin", VIRTUAL_ENV=str(venv))
    env.pop("MLFLOW_TRACKING_URI", None)
    env.pop("RAY_ADDRESS", None)
    done = subprocess.run(
        ["pcpg", "run", "mini.yaml", "--quiet"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    out = done.stdout.splitlines()
    store = f"sqlite:///{tmp_path / 'mlflow.db'}"
    assert f"start the UI: mlflow ui --backend-store-uri {store}" in out, out[-8:]
    assert "uv run" not in done.stdout + done.stderr
    summary = tmp_path / "runs" / "mini" / "summary"
    metrics = json.loads((summary / "metrics.json").read_text())
    assert 0.0 <= metrics["pcpg/accuracy/p1"] <= 1.0
    assert (tmp_path / "runs" / "mini" / "report" / "report.html").is_file()
    assert f"report: {tmp_path / 'runs' / 'mini' / 'report' / 'report.html'}" in out
    # the installed package, not this checkout, ran
    where = subprocess.run(
        ["python", "-c", "import pcpg_dist; print(pcpg_dist.__file__)"],
        env=env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        check=True,
    )
    assert Path(where.stdout.strip()).is_relative_to(venv)
