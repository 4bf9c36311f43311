"""Content-keyed units of work: a finished unit is never recomputed, a damaged one never used.

A unit's key hashes its config slice and its inputs' keys. Its folder ``ROOT/<stage>/<key>/`` is
complete when ``done.json`` exists; that file is written last (atomically) and records the size
and SHA-256 of every file in the folder. A unit killed halfway is simply redone; a finished unit
whose files were truncated, edited or removed since fails its check and is recomputed, never
published. Only the driver writes here: tasks return their files as bytes (:func:`pcpg_dist.common.file_bytes.files_of`).
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path
from typing import Any

from pcpg_dist.common.errors import DataError
from pcpg_dist.common.file_bytes import write_files
from pcpg_dist.common.files import atomic_write_bytes, sha256_file

DONE = "done.json"


def _listing(folder: Path) -> dict[str, list]:
    """``relative path -> [size, sha256]`` of every file under ``folder`` but the marker."""
    return {
        p.relative_to(folder).as_posix(): [p.stat().st_size, sha256_file(p)]
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != DONE
    }


class Cache:
    """Unit folders under ``root``; ``done(stage, key)`` says whether a unit finished intact."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.rejected: list[str] = []  # units whose files failed their check (recomputed)

    def path(self, stage: str, key: str) -> Path:
        return self.root / stage / key

    def done(self, stage: str, key: str) -> dict | None:
        """The unit's ``done.json`` info if it finished and its files are intact, else ``None``."""
        folder = self.path(stage, key)
        marker = folder / DONE
        if not marker.is_file():
            return None
        try:
            info = json.loads(marker.read_text())
            files = info.get("files") if isinstance(info, dict) else None
        except (ValueError, UnicodeDecodeError):
            files = None
        if not isinstance(files, dict) or _listing(folder) != files:
            self.rejected.append(f"{stage}/{key}")
            return None
        return info

    def start(self, stage: str, key: str) -> Path:
        """A clean folder for a unit about to be (re)computed."""
        path = self.path(stage, key)
        if path.exists():
            shutil.rmtree(path)
        path.mkdir(parents=True)
        return path

    def finish(self, stage: str, key: str, info: dict, listing: dict | None = None) -> None:
        """Mark a unit complete: its marker lists every file's size and hash (``listing``, where
        the caller has them; else read back from the folder)."""
        folder = self.path(stage, key)
        files = _listing(folder) if listing is None else listing
        atomic_write_bytes(
            folder / DONE,
            json.dumps({**info, "files": files}, indent=1, sort_keys=True, default=str).encode(),
        )

    def store(self, stage: str, key: str, files: dict[str, bytes], info: dict) -> Path:
        """Start, write a task's files and finish a unit in one call (the driver's only write)."""
        folder = self.start(stage, key)
        # written in place, not synced one by one: the folder is new, and the marker, written
        # last and synced, lists every file's hash, so a file that a kill or a power cut cut
        # short fails `done` and the unit is computed again
        write_files(folder, files, atomic=False)
        # hashed from the bytes in hand, not read back: a file a kill cut short still fails
        # `done`, which hashes what is on disk
        listing = {
            rel: [len(blob), hashlib.sha256(blob).hexdigest()] for rel, blob in files.items()
        }
        self.finish(stage, key, info, listing)
        return folder

    def read_json(self, stage: str, key: str, name: str) -> Any:
        try:
            return json.loads((self.path(stage, key) / name).read_text())
        except (OSError, ValueError) as e:
            raise DataError(
                f"cache entry {stage}/{key}/{name} is unreadable ({e}); delete the folder "
                f"{self.path(stage, key)} and rerun"
            ) from None
