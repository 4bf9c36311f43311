"""Commands as the user types them, the way pcpg was started: what pcpg prints for the user to
run next (the MLflow UI, the Optuna dashboard, `pcpg run` on a tuned config, `ray start`) must
work when pasted into the shell pcpg was started from.

- Under ``uv run`` (uv sets ``UV`` for the processes it starts): ``uv run TOOL``.
- Else, where the shell's ``PATH`` finds this environment's own ``TOOL`` (an activated venv, a
  ``pip install --user``, a system install): ``TOOL``.
- Else (a venv's python called by its path, the venv not activated): the tool's full path.
- A tool that is not installed beside pcpg: ``TOOL``, with the ``pip install`` that brings it.
"""

from __future__ import annotations

import os
import shlex
import shutil
import sys
from pathlib import Path


def under_uv() -> bool:
    """Whether pcpg was started by ``uv run`` (uv names itself in ``UV`` for what it runs)."""
    return bool(os.environ.get("UV"))


def command(tool: str, *args: str, package: str | None = None) -> str:
    """``tool args...`` as the user would type it here (see the module's doc); ``package``: the
    distribution to ``pip install`` when the tool is not installed beside pcpg."""
    rest = "".join(f" {shlex.quote(str(a))}" for a in args)
    own = Path(sys.executable).parent / tool
    if not own.is_file():  # not in this environment (a dev-only tool under a wheel install)
        found = shutil.which(tool)
        if found:
            return f"{tool}{rest}"
        return f"{tool}{rest}  (not installed: pip install {package or tool})"
    if under_uv():
        return f"uv run {tool}{rest}"
    found = shutil.which(tool)
    if found and Path(found).resolve() == own.resolve():
        return f"{tool}{rest}"
    return f"{shlex.quote(str(own))}{rest}"
