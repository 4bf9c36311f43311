"""Files as values: a task returns its files as ``{relative path: bytes}`` and the driver writes
them, so no worker needs the driver's disk."""

from __future__ import annotations

from pathlib import Path

from pcpg_dist.common.disk import disk_full, is_disk_full
from pcpg_dist.common.files import atomic_write_bytes, confined


def files_of(folder: str | Path) -> dict[str, bytes]:
    """Every file under ``folder`` as ``relative path -> bytes`` (what a task returns)."""
    folder = Path(folder)
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def write_files(folder: Path, files: dict[str, bytes], atomic: bool = True) -> None:
    """Write a task's returned files under ``folder``; a name that would leave it is refused.
    ``atomic``: each file written aside, synced and renamed into place; without, written in place
    (a cache unit's new folder, complete only once its marker, written last, lists the files)."""
    for rel, blob in files.items():
        target = folder
        for part in rel.split("/"):
            target = confined(target, part, "result file")
        target.parent.mkdir(parents=True, exist_ok=True)
        if atomic:
            atomic_write_bytes(target, blob)
        else:
            try:
                with open(target, "xb") as f:  # "x": a name given twice is an error
                    f.write(blob)
            except OSError as e:
                if is_disk_full(e):  # one line naming the file, as an atomic write says it
                    raise disk_full(target, len(blob)) from None
                raise
