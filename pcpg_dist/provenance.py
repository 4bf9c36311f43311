"""Where a result came from: git commit, package versions, machine, uv.lock hash."""

from __future__ import annotations

import hashlib
import platform
import subprocess
from functools import cache
from importlib import metadata
from pathlib import Path

import pcpg_dist

PACKAGES = ("torch", "ray", "mlflow", "optuna", "numpy", "scikit-learn", "pyarrow", "pydantic", "numba")
_ROOT = Path(pcpg_dist.__file__).resolve().parent.parent


@cache
def git_commit() -> str:
    """HEAD of the checkout the package runs from (with '+dirty' if it has changes), or 'unknown'."""
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=_ROOT, capture_output=True, text=True,
                              timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=_ROOT,
                               capture_output=True, text=True, timeout=5).stdout.strip()
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


def machine() -> dict[str, str]:
    import os

    return {"platform": platform.platform(), "processor": platform.machine(),
            "cpus": str(os.cpu_count()), "node": platform.node()}


def provenance() -> dict:
    return {"git_commit": git_commit(), "uv_lock": uv_lock_hash(), "versions": versions(),
            "machine": machine()}
