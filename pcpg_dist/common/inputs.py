"""The input policy, in one place: what pcpg reads from disk and how.

Every file and folder pcpg reads (layouts, step tables, Minari datasets, dataset manifests,
clustering models, agents folders, run folders, summary files) is checked here before it is
opened:

- only **regular files and folders**: a FIFO, socket or device is refused with one line (reading
  one would block or never end), never skipped in silence;
- a **symlink is followed only if it resolves inside the folder it belongs to** (the folder the
  config, the command line or a manifest names): a link that leads out of it is refused with one
  line naming the link and its target. A link within the folder (``latest -> run-3``) is fine;
- a file has a **size limit** where the reader would hold it whole.

Writers create their files without following links inside the output folder
(:func:`pcpg_dist.common.files.atomic_write_bytes` renames over the link itself, and
:func:`writable_folder` refuses an output folder that is a link leading out of its parent).
docs/reliability.md states the policy for users.
"""

from __future__ import annotations

import json
import os
import stat
from collections.abc import Iterable
from pathlib import Path

from pcpg_dist.common.errors import DataError, first_line


def kind_of(path: Path) -> str:
    """What ``path`` is, in words, for a message ('a FIFO', 'a socket', 'a device', ...)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return "missing"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISDIR(mode):
        return "a folder"
    return "a regular file" if stat.S_ISREG(mode) else "a special file"


def inside(path: Path, folder: Path | None, what: str) -> Path:
    """``path``, checked: where it is (or passes through) a link, it resolves inside ``folder``
    (None: no folder to stay in, e.g. a path the user typed). Returns the path as given."""
    path = Path(path)
    if folder is None:
        return path
    root = Path(folder).resolve()
    target = path.resolve()
    if not target.is_relative_to(root):
        raise DataError(
            f"{what} {path}: a link to {target}, outside {folder}; refusing to read it "
            f"(a link is followed only within its folder: copy the file into the folder)"
        )
    return path


def input_file(
    path: Path,
    what: str = "file",
    *,
    folder: Path | None = None,
    max_bytes: int | None = None,
    missing: str = "not found",
) -> Path:
    """A regular file to read (inside ``folder`` where given, at most ``max_bytes``), else one
    :class:`DataError` line naming it and what is allowed."""
    path = Path(path)
    inside(path, folder, what)
    kind = kind_of(path)
    if kind == "missing":
        raise DataError(f"{what} {path}: {missing}")
    if kind != "a regular file":
        raise DataError(f"{what} {path}: {kind}, not a regular file; name a regular file")
    if max_bytes is not None:
        size = path.stat().st_size
        if size > max_bytes:
            raise DataError(f"{what} {path}: {size:,} bytes, over the limit of {max_bytes:,} bytes")
    return path


def input_folder(path: Path, what: str = "folder", *, folder: Path | None = None) -> Path:
    """A folder to read (inside ``folder`` where given), else one :class:`DataError` line."""
    path = Path(path)
    inside(path, folder, what)
    kind = kind_of(path)
    if kind == "missing":
        raise DataError(f"{what} {path}: not found")
    if kind != "a folder":
        raise DataError(f"{what} {path}: {kind}, not a folder")
    return path


def entries(
    folder: Path, what: str, *, suffixes: Iterable[str] | None = None, dirs: bool = False
) -> list[Path]:
    """The entries of ``folder`` pcpg reads, in name order: regular files (``suffixes``: only
    those endings, any case) or, with ``dirs``, folders. A link leading out of the folder, or a
    special file among the named entries, is one line, never skipped."""
    found = []
    wanted = tuple(s.lower() for s in suffixes) if suffixes is not None else None
    for p in sorted(Path(folder).iterdir()):
        if wanted is not None and not p.name.lower().endswith(wanted):
            continue
        if p.is_symlink():
            inside(p, folder, what)
        kind = kind_of(p)
        if kind == "a folder":
            if dirs:
                found.append(p)
            continue
        if kind == "a regular file":
            if not dirs:
                found.append(p)
            continue
        if kind == "missing":  # a dangling link
            raise DataError(f"{what} {p}: a link to nothing ({os.readlink(p)})")
        raise DataError(f"{what} {p}: {kind}, not a regular file; remove it or name another folder")
    return found


def writable_folder(path: Path, what: str = "output folder", *, folder: Path | None = None) -> Path:
    """An output folder pcpg may create or fill: not a link that leads out of ``folder`` (the
    output folder the user named, for a sub-folder pcpg makes in it; default: its parent), not a
    special file. Its files are then written by name inside it."""
    path = Path(path)
    if path.is_symlink():
        inside(path, path.parent if folder is None else folder, what)
    kind = kind_of(path)
    if kind not in ("missing", "a folder"):
        raise DataError(f"{what} {path}: {kind}, not a folder")
    return path


JSON_DEPTH = 64  # nesting pcpg accepts in a JSON file it reads (its own files nest a few levels)


def json_text(text: str | bytes, what: str, *, max_depth: int = JSON_DEPTH) -> object:
    """``text`` parsed as JSON, nested at most ``max_depth`` levels, else one :class:`DataError`
    line naming ``what`` (a file, or a file's key holding JSON text)."""
    deep = DataError(
        f"{what}: JSON nested more than {max_depth} levels deep; refusing to read it "
        f"(at most {max_depth} levels of [] and {{}})"
    )
    try:
        data = json.loads(text)
    except RecursionError:  # deeper than Python's parser goes (100,000 brackets)
        raise deep from None
    except ValueError as e:
        raise DataError(f"{what}: not valid JSON ({first_line(e)})") from None
    todo = [(data, 1)]
    while todo:  # a loop, not recursion: the depth is what is being checked
        value, depth = todo.pop()
        if isinstance(value, dict | list):
            if depth > max_depth:
                raise deep
            todo.extend(
                (v, depth + 1) for v in (value.values() if isinstance(value, dict) else value)
            )
    return data


def input_json(
    path: Path,
    what: str = "file",
    *,
    folder: Path | None = None,
    max_bytes: int = 16 << 20,
    max_depth: int = JSON_DEPTH,
) -> dict:
    """A JSON object from a regular file (:func:`input_file`: inside ``folder``, at most
    ``max_bytes``) nested at most ``max_depth`` levels, else one :class:`DataError` line."""
    path = input_file(path, what, folder=folder, max_bytes=max_bytes)
    try:
        text = path.read_bytes()
    except OSError as e:
        raise DataError(f"{what} {path}: unreadable ({e.strerror or first_line(e)})") from None
    data = json_text(text, f"{what} {path}", max_depth=max_depth)
    if not isinstance(data, dict):
        raise DataError(f"{what} {path}: expected a JSON object, found {type(data).__name__}")
    return data


def write_target(folder: Path, relative: Path | str, what: str = "output") -> Path:
    """``folder / relative`` for a writer, checked before anything is written: no part of it below
    ``folder`` is a link that leads out of ``folder`` (writing through it would put the files
    elsewhere); a link that stays inside is fine. Returns the path."""
    folder = Path(folder)
    path = folder
    for part in Path(relative).parts:
        path = path / part
        if path.is_symlink() and not path.resolve().is_relative_to(folder.resolve()):
            raise DataError(
                f"{what} {path}: a link to {path.resolve()}, outside {folder}; refusing to write "
                f"through it (remove the link, or pick another output folder)"
            )
    return path
