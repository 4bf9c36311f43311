"""What pcpg prints for the user to run next fits how pcpg was started: ``uv run TOOL`` under
``uv run``, the plain ``TOOL`` where the shell finds this environment's, its full path where it
does not, and the ``pip install`` that brings a tool that is not installed."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

SNIPPET = (
    "from pcpg_dist.common.commands import command; "
    "print(command('mlflow', 'ui', '--backend-store-uri', 'sqlite:///a b.db')); "
    "print(command('no-such-tool-xyz', package='no-such-dist'))"
)
BIN = Path(sys.executable).parent


def shown(env: dict[str, str]) -> list[str]:
    out = subprocess.run(
        [sys.executable, "-c", SNIPPET], env=env, capture_output=True, text=True, check=True
    )
    return out.stdout.splitlines()


def test_under_uv_the_command_is_uv_run():
    env = {**os.environ, "UV": "/somewhere/uv"}
    assert shown(env)[0] == "uv run mlflow ui --backend-store-uri 'sqlite:///a b.db'"


def test_an_activated_environment_gets_the_plain_tool():
    env = {k: v for k, v in os.environ.items() if k != "UV"}
    env["PATH"] = f"{BIN}{os.pathsep}{env.get('PATH', '')}"
    assert shown(env)[0] == "mlflow ui --backend-store-uri 'sqlite:///a b.db'"


def test_a_venv_called_by_its_path_gets_the_full_path_and_a_missing_tool_its_install():
    env = {k: v for k, v in os.environ.items() if k != "UV"}
    env["PATH"] = "/usr/bin:/bin"  # this environment's bin is not on it
    ui, missing = shown(env)
    assert ui == f"{BIN / 'mlflow'} ui --backend-store-uri 'sqlite:///a b.db'"
    assert missing == "no-such-tool-xyz  (not installed: pip install no-such-dist)"


def test_progress_goes_to_a_log_file_as_lines_while_the_work_runs(tmp_path):
    """Progress with stderr a file: a line at the start, every PCPG_PROGRESS_SECONDS, and at
    the end (it printed nothing for minutes, then one line)."""
    code = (
        "from pcpg_dist.common.progress import progress_bar\n"
        "import time\n"
        "with progress_bar('Step C: BC groups', total=3) as advance:\n"
        "    for _ in range(3):\n"
        "        time.sleep(0.05); advance()\n"
    )
    log = tmp_path / "err.log"
    env = {**os.environ, "PCPG_PROGRESS_SECONDS": "0"}
    with open(log, "w") as err:
        subprocess.run([sys.executable, "-c", code], stderr=err, env=env, check=True)
    lines = log.read_text().splitlines()
    assert lines[0].startswith("Step C: BC groups: 0/3 (")
    assert [line.split(" (")[0] for line in lines[1:]] == [
        "Step C: BC groups: 1/3",
        "Step C: BC groups: 2/3",
        "Step C: BC groups: 3/3",
    ]
