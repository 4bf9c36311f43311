"""Content-keyed units of work: a finished unit is never recomputed.

A unit's key hashes its config slice and its inputs' keys. Its folder ``ROOT/<stage>/<key>/`` is
complete when ``done.json`` exists; that file is written last (atomically), so a unit killed
halfway is simply redone, and a finished one is reused by every later run.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path
from typing import Any

from pcpg_dist.dataset import atomic_write_bytes

DONE = "done.json"


def content_key(*parts: Any) -> str:
    """A short stable hash of JSON-able parts (pydantic models are dumped first)."""

    def norm(x: Any) -> Any:
        if hasattr(x, "model_dump"):
            return x.model_dump(mode="json")
        if isinstance(x, Path):
            return str(x)
        if isinstance(x, dict):
            return {str(k): norm(v) for k, v in x.items()}
        if isinstance(x, list | tuple):
            return [norm(v) for v in x]
        return x

    blob = json.dumps([norm(p) for p in parts], sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:20]


class Cache:
    """Unit folders under ``root``; ``done(stage, key)`` says whether a unit finished."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)

    def path(self, stage: str, key: str) -> Path:
        return self.root / stage / key

    def done(self, stage: str, key: str) -> dict | None:
        marker = self.path(stage, key) / DONE
        if not marker.is_file():
            return None
        try:
            return json.loads(marker.read_text())
        except ValueError:
            return None

    def start(self, stage: str, key: str) -> Path:
        """A clean folder for a unit about to be (re)computed."""
        path = self.path(stage, key)
        if path.exists():
            shutil.rmtree(path)
        path.mkdir(parents=True)
        return path

    def finish(self, stage: str, key: str, info: dict) -> None:
        atomic_write_bytes(self.path(stage, key) / DONE,
                           json.dumps(info, indent=1, sort_keys=True, default=str).encode())
