"""A full disk, said in one line: which path could not be written, how much space is free there
and what to do, wherever it happens (data, cache, MLflow store, artifacts, report).

A full disk is never taken for anything else (the MLflow store is not "half-created" because
SQLite could not grow it), nothing is moved aside, and every stage's outputs are written
atomically, so rerunning the same command once space is freed resumes where the run stopped.
"""

from __future__ import annotations

import errno
import shutil
from pathlib import Path

from pcpg_dist.common.errors import PcpgError

FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})
#: what libraries say when the disk is full without an errno (SQLite, Arrow, MLflow wrapping them)
FULL_TEXTS = ("database or disk is full", "no space left on device", "disk quota exceeded")


class DiskFullError(PcpgError):
    """No space left where pcpg writes; the message names the path and the free space."""


def is_disk_full(error: BaseException) -> bool:
    """Whether ``error`` or anything that caused it is a full disk."""
    seen: set[int] = set()
    e: BaseException | None = error
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError) and e.errno in FULL_ERRNOS:
            return True
        if any(t in str(e).lower() for t in FULL_TEXTS):
            return True
        e = e.__cause__ or e.__context__
    return False


def free_bytes(path: Path) -> int | None:
    """Free space on the filesystem holding ``path`` (its nearest existing folder)."""
    p = Path(path).absolute()
    for folder in (p, *p.parents):
        if folder.exists():
            try:
                return shutil.disk_usage(folder).free
            except OSError:
                return None
    return None


def _size(n: int) -> str:
    for unit in ("bytes", "KB", "MB", "GB"):
        if n < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} GB"


def disk_full(path: Path | str, needed: int | None = None, what: str = "") -> DiskFullError:
    """The one-line error for ``path`` that could not be written (``needed`` bytes where known)."""
    free = free_bytes(Path(path))
    room = f"{_size(free)} free there" if free is not None else "free space unknown"
    need = f"; it needs about {_size(needed)}" if needed else ""
    return DiskFullError(
        f"{what + ' ' if what else ''}{path}: no space left on the device ({room}{need}); free some "
        f"space and rerun the same command: everything finished so far is kept"
    )
