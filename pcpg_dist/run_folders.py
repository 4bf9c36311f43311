"""The folders of a run that `pcpg run` rewrites, and the check that keeps outputs out of them.

A run's folder (``WORKDIR/NAME``, or a sweep's ``…/sweep/points/POINT``) holds ``cache/`` (units
that are removed and redone when their listing no longer matches), ``summary/`` (cleared and
rebuilt) and ``agents/`` (replaced). A file a user writes in there is deleted without a word by the
next run, and in ``cache/`` it also invalidates the unit it lands in.
"""

from __future__ import annotations

from pathlib import Path

from pcpg_dist.errors import ConfigError

REWRITTEN = ("cache", "summary", "agents")


def is_run_folder(folder: Path) -> bool:
    """A folder `pcpg run` writes: its cache lock or its summary's record is there."""
    return (folder / "cache.lock").exists() or (folder / "summary" / "run.json").is_file()


def rewritten_folder(path: Path) -> Path | None:
    """The run folder's ``cache``/``summary``/``agents`` that ``path`` is (or lies in), else None."""
    at = Path(path).resolve()
    for folder in (at, *at.parents):
        if folder.name in REWRITTEN and is_run_folder(folder.parent):
            return folder
    return None


def check_outside_run(path: Path, option: str = "--out") -> None:
    """Refuse an output inside a run's ``cache/``, ``summary/`` or ``agents/`` (one line)."""
    folder = rewritten_folder(path)
    if folder is not None:
        raise ConfigError(f"{option} {path}: inside {folder}, which the next `pcpg run` of {folder.parent} "
                          f"rewrites (deleting files it did not write); choose a place outside the run's "
                          f"{', '.join(f'{n}/' for n in REWRITTEN)}")
