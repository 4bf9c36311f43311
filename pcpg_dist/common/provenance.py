"""Where a result came from: git commit, package versions, machine, uv.lock hash."""

from __future__ import annotations

import hashlib
import platform
import subprocess
from functools import cache
from importlib import metadata
from pathlib import Path

import pcpg_dist

PACKAGES = (
    "torch",
    "ray",
    "mlflow",
    "optuna",
    "numpy",
    "scikit-learn",
    "pyarrow",
    "pydantic",
    "numba",
)
_ROOT = Path(pcpg_dist.__file__).resolve().parent.parent


@cache
def git_commit() -> str:
    """HEAD of the checkout the package runs from (with '+dirty' if it has changes), or 'unknown'."""
    try:
        head = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=_ROOT,
            capture_output=True,
            text=True,
            timeout=5,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=_ROOT,
            capture_output=True,
            text=True,
            timeout=5,
        ).stdout.strip()
        return head + ("+dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


@cache
def uv_lock_hash() -> str:
    lock = _ROOT / "uv.lock"
    return hashlib.sha256(lock.read_bytes()).hexdigest()[:16] if lock.is_file() else "unknown"


def versions() -> dict[str, str]:
    out = {"pcpg-dist": pcpg_dist.__version__, "python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _memory() -> str:
    import os

    try:
        return f"{os.sysconf('SC_PAGE_SIZE') * os.sysconf('SC_PHYS_PAGES') / 2**30:.1f} GiB"
    except (ValueError, OSError, AttributeError):
        return "unknown"


def machine() -> dict[str, str]:
    """The machine a run ran on, as the report's table shows it (strings, readable units)."""
    import os

    return {
        "platform": platform.platform(),
        "architecture": platform.machine(),
        "cpu": _cpu_model(),
        "cpus": str(os.cpu_count()),
        "memory": _memory(),
        "node": platform.node(),
    }


def provenance() -> dict:
    return {
        "git_commit": git_commit(),
        "uv_lock": uv_lock_hash(),
        "versions": versions(),
        "machine": machine(),
    }
