"""Files written and read safely: atomic writes, content hashes, names from data kept as plain names.

Every layer writes files (datasets, caches, summaries, reports, agents); these helpers live at the
bottom so that each of them can use the same guarantees without importing the layer that first
needed them: a crash never leaves a half file, a written file gets the mode ``open()`` would give
it, and a name read from data never becomes a path that leaves its folder.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import tempfile
from pathlib import Path

from pcpg_dist.common.disk import disk_full, is_disk_full
from pcpg_dist.common.errors import DataError

# mkstemp creates 0600 files; written files get what open() would give them under the user's umask.
_UMASK = os.umask(0o022)
os.umask(_UMASK)
FILE_MODE = 0o666 & ~_UMASK

SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")


def confined(base: Path, name: str, what: str = "name") -> Path:
    """``base / name`` for a name that came from data (an env, a manifest entry): one plain file or
    folder name, never a path that could leave ``base``; a DataError otherwise."""
    if not isinstance(name, str) or not SAFE_NAME.match(name) or ".." in name or len(name) > 200:
        raise DataError(
            f"{what} {str(name)[:80]!r} is not a plain name (letters, digits, '_', '.', '+', "
            f"'-'; no '/', no '..'): refusing to use it as a path under {base}"
        )
    return Path(base) / name


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def temp_beside(path: Path) -> tuple[int, str]:
    """A temporary file in ``path``'s folder; an error names ``path`` (not the temporary name)."""
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "it is a folder; name a file", str(path))
    if path.exists() and not path.is_file():  # a FIFO or a device: the rename would replace it
        raise OSError(
            errno.EINVAL,
            "it is not a regular file (a FIFO, socket or device); name a regular file",
            str(path),
        )
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as e:
        raise OSError(e.errno, e.strerror, str(path)) from None


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write to a temporary file beside ``path`` and rename it: a crash never leaves a half file."""
    path = Path(path)
    fd, tmp = temp_beside(path)
    os.fchmod(fd, FILE_MODE)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(e, OSError) and is_disk_full(e):  # named by its path, not the temporary's
            raise disk_full(path, len(data)) from None
        raise


def read_json(path: Path) -> dict:
    """A JSON object from ``path``; one-line DataError for a file unreadable or not an object."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError) as e:  # RecursionError: brackets nested too deep
        raise DataError(f"{path}: unreadable ({e})") from None
    if not isinstance(data, dict):
        raise DataError(f"{path}: expected a JSON object, found {type(data).__name__}")
    return data
