"""A full disk, on a real small filesystem (tmpfs; the tests run as root here and skip where
mounting is not allowed): one line naming the path and the free space, exit 2, no traceback; the
MLflow store is never taken for a half-created one; rerunning once space is freed finishes."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from mini_config import mini_yaml

MINI = mini_yaml(episodes=3000, epochs=30, figures=False)

pytestmark = pytest.mark.slow


@pytest.fixture
def small_disk(tmp_path):
    """A 300 KB tmpfs, unmounted at the end; ``resize(size)`` frees space."""
    where = tmp_path / "disk"
    where.mkdir()
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=300k", "tmpfs", str(where)], capture_output=True
    )
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.decode().strip()[:200]}")

    def resize(size: str) -> None:
        subprocess.run(["mount", "-o", f"remount,size={size}", str(where)], check=True)

    try:
        yield where, resize
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False)


def run_here(folder: Path, capsys, *extra: str) -> tuple[int, list[str]]:
    from pcpg_dist.cli import main

    code = main(["-q", "run", str(folder / "mini.yaml"), "--workdir", str(folder / "runs"), *extra])
    return code, capsys.readouterr().err.strip().splitlines()


def test_a_full_disk_is_one_line_and_a_rerun_after_freeing_space_finishes(
    ray_session, small_disk, monkeypatch, capsys
):
    disk, resize = small_disk
    monkeypatch.chdir(disk)  # the default MLflow store ./mlflow.db lives on the small disk
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    (disk / "mini.yaml").write_text(MINI)
    code, err = run_here(disk, capsys)
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("pcpg: error: ") and "no space left on the device" in err[0]
    assert str(disk) in err[0] and "free there" in err[0] and "rerun the same command" in err[0]
    assert not list(disk.glob("mlflow.db.incomplete-*"))  # not misdiagnosed, nothing moved aside
    assert not list(disk.rglob("*.tmp"))  # no half-written file left
    resize("300m")
    code, err = run_here(disk, capsys)
    assert code == 0, err
    assert (disk / "runs" / "mini" / "summary" / "metrics.json").is_file()


def test_a_full_disk_under_the_data_is_one_line(ray_session, small_disk, monkeypatch, capsys):
    disk, resize = small_disk
    monkeypatch.chdir(disk)
    (disk / "mini.yaml").write_text(MINI)
    resize("40k")
    code, err = run_here(disk, capsys, "--no-tracking")
    assert code == 2 and len(err) == 1, err
    assert "no space left on the device" in err[0] and str(disk / "runs") in err[0], err
    assert not list(disk.rglob("*.tmp"))
