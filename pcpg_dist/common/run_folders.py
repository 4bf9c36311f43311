"""The folders of a run that `pcpg run` rewrites, and the check that keeps outputs out of them.

A run's folder (``WORKDIR/NAME``, or a sweep's ``…/sweep/points/POINT``) holds ``cache/`` (units
that are removed and redone when their listing no longer matches), ``summary/`` (cleared and
rebuilt) and ``agents/`` (replaced). A file a user writes in there is deleted without a word by the
next run, and in ``cache/`` it also invalidates the unit it lands in.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path
from typing import Any

from pcpg_dist.common.errors import ConfigError, DataError
from pcpg_dist.common.files import atomic_write_bytes, read_json, sha256_file

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
        raise ConfigError(
            f"{option} {path}: inside {folder}, which the next `pcpg run` of {folder.parent} "
            f"rewrites (deleting files it did not write); choose a place outside the run's "
            f"{', '.join(f'{n}/' for n in REWRITTEN)}"
        )


# --------------------------------------------------------------------------- the agents' index
AGENTS_INDEX = (
    "index.json"  # RUN/agents/index.json: which files `pcpg run` wrote for which environment
)

#: the files and folders a run writes beside its environments' folders (summary/, agents/, report/,
#: a sweep's folder); an environment of one of these names would collide with them only once every
#: stage had run (tests/common/test_run_folders.py checks the list against a real run)
BESIDE_UNITS = frozenset(
    {
        "metrics.json",
        "accuracy_vs_p.csv",
        "accuracy_vs_p.json",
        "accuracy_vs_p.png",
        "clustering.csv",
        "clustering.json",
        "run.json",
        AGENTS_INDEX,
        "figures",
        "report.html",
        "report.md",
        "points",
        "summary.csv",
        "sweep.json",
        *REWRITTEN,
        "report",
    }
)


def check_unit_name(name: str) -> None:
    """An environment (unit) name that is not a file or folder a run writes beside it (compared
    without case, for case-insensitive file systems)."""
    if name.lower() in BESIDE_UNITS:
        raise DataError(
            f"environment name {name!r} is the name of a file or folder pcpg writes beside the "
            f"environments' folders ({', '.join(sorted(BESIDE_UNITS))}); rename that "
            f"environment (for logs: its 'env' value)"
        )


def write_agents_index(agents: Path) -> None:
    """Record the SHA-256 of every file of ``agents/<env>/``, per environment, so a file moved,
    swapped or deleted between environments is found (the cells carry no environment name)."""
    envs = {
        env.name: {f.name: sha256_file(f) for f in sorted(env.iterdir()) if f.is_file()}
        for env in sorted(agents.iterdir())
        if env.is_dir()
    }
    atomic_write_bytes(
        agents / AGENTS_INDEX, json.dumps({"format": 1, "environments": envs}, indent=1).encode()
    )


def check_run_agents(agents: Path) -> None:
    """A run's agents folder holds exactly what the run wrote (one line naming the first file or
    environment that differs): the files its ``index.json`` lists, each with its hash (a folder
    written before the index has none to check), for exactly the environments its summary reports
    (``summary/<env>/metrics.json``). Any other agents folder (an MLflow download) passes."""
    _check_agents_index(agents)
    summary = agents.parent / "summary"
    if agents.name != "agents" or not (summary / "run.json").is_file():
        return
    envs = {d.name for d in summary.iterdir() if (d / "metrics.json").is_file()}
    found = {d.name for d in agents.iterdir() if d.is_dir() and any(d.glob("*.pt"))}
    missing, extra = sorted(envs - found), sorted(found - envs)
    if missing or extra:
        said = "; ".join(
            x
            for x in (
                f"no agents for {', '.join(missing)}" if missing else "",
                f"agents for {', '.join(extra)}, which it does not report" if extra else "",
            )
            if x
        )
        raise DataError(
            f"{agents}: does not match the run's summary ({summary}): {said}; rerun pcpg run "
            f"for this run to write its agents again"
        )


def _check_agents_index(agents: Path) -> None:
    path = agents / AGENTS_INDEX
    if not path.exists():
        return
    envs = read_json(path).get("environments")
    if not isinstance(envs, dict) or not all(isinstance(f, dict) for f in envs.values()):
        raise DataError(f"{path}: 'environments' must map each environment to its files' SHA-256")
    found = {
        env.name: {f.name for f in env.iterdir() if f.is_file()}
        for env in agents.iterdir()
        if env.is_dir()
    }
    for env in sorted(set(envs) | set(found)):
        for name in sorted(set(envs.get(env, {})) | found.get(env, set())):
            file = agents / env / name
            want = envs.get(env, {}).get(name)
            if want is None or not file.is_file() or sha256_file(file) != want:
                said = (
                    "missing"
                    if want is not None and not file.is_file()
                    else "not listed in " + AGENTS_INDEX
                    if want is None
                    else "not the file the run wrote here (its SHA-256 differs)"
                )
                raise DataError(
                    f"{file}: {said}; the agents folder is not as pcpg run left it (rerun pcpg run)"
                )


def slug(text: str, identity: Any, fallback: str = "x") -> str:
    """A folder name for ``text``: its letters, digits and ``._=-`` (other runs become '-'), at most
    80 characters, plus a short hash of ``identity`` (what sets it apart, kept when text is cut)."""
    digest = hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()).hexdigest()[
        :8
    ]
    safe = re.sub(r"[^A-Za-z0-9._=-]+", "-", text)[:80].strip("-.") or fallback
    return f"{safe}-{digest}"
