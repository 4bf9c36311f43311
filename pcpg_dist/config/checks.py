"""Checks shared by every domain's settings: names that become folder names, files a config points
at, and paths relative to the config file. Pydantic only, and naming no domain, so each domain's
settings module (``pcpg_dist/domains/<name>/settings.py``) builds on them.
"""

from __future__ import annotations

import re
from pathlib import Path

from pydantic import ValidationInfo

NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]*$"
MAX_NAME = 100  # names become folder and file names (255 bytes at most on common file systems)
MAX_LEVEL_BYTES = 1 << 20  # a level or layout file is a screenful of characters


def safe_name(value: str, what: str) -> str:
    """Names become folder and run names: no path separators, no '..', nothing absolute."""
    if len(value) > MAX_NAME:
        raise ValueError(
            f"{what} {value[:40]!r}... has {len(value)} characters; at most {MAX_NAME} are allowed"
        )
    if not re.match(NAME_PATTERN, value) or ".." in value:
        raise ValueError(
            f"{what} {value!r} must be letters, digits, '_', '.', '-' (no '/', no '..')"
        )
    return value


def check_text_file(
    path: Path,
    what: str,
    max_bytes: int = MAX_LEVEL_BYTES,
    utf8: bool = True,
    folder: Path | None = None,
) -> None:
    """A file the config points at must be a regular file of at most ``max_bytes`` bytes of UTF-8
    text (a FIFO or /dev/zero would block or never end; a binary file is the wrong file); one
    named in a ``folder`` must not be a link out of it (:mod:`pcpg_dist.common.inputs`)."""
    if folder is not None:
        from pcpg_dist.common.inputs import inside

        inside(path, folder, what)
    if not path.is_file():
        raise ValueError(
            f"{what} {path} " + ("is not a regular file" if path.exists() else "not found")
        )
    size = path.stat().st_size
    if size > max_bytes:
        raise ValueError(
            f"{what} {path} has {size} bytes; at most {max_bytes} are allowed (wrong file?)"
        )
    if not utf8:
        return
    raw = path.read_bytes()
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise ValueError(
            f"{what} {path}, line {line}: not UTF-8 text (byte {e.start}); save it as UTF-8"
        ) from None


def relative_to_config(v: Path, info: ValidationInfo) -> Path:
    """Relative paths in a config file are relative to the file's folder; ``~`` is the home folder."""
    v = v.expanduser()
    base = (info.context or {}).get("base_dir")
    return (Path(base) / v).resolve() if base is not None and not v.is_absolute() else v
