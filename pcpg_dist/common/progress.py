"""Terminal output: results on stdout, progress and logs on stderr, library noise silenced.

``out`` prints results (tables, paths, commands) on stdout with soft wrapping, so a long command
stays one line that can be copied, and 160 columns wide where stdout is a file or a pipe;
``console`` and the progress bars (rich) write to stderr and degrade to a final line when stderr
is not a terminal. :func:`setup_output` is called once by the CLI with its ``-q/--quiet`` and
``--verbose`` flags.
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

RESULT_WIDTH = 160  # columns of the results when stdout is not a terminal

console = Console(stderr=True)
#: results; written to a file or a pipe (no terminal, no COLUMNS) tables keep their numbers whole
#: instead of fitting rich's default 80 columns (which cut 0.953 to "0.9…")
out = Console(
    soft_wrap=True,
    width=None if sys.stdout.isatty() or "COLUMNS" in os.environ else RESULT_WIDTH,
)

# Ray logs this at every private start although the default it announces is the secure one.
_RAY_TOKEN_NOTICE = "Token authentication is enabled for this Ray cluster"
_RAY_AUTH_LOGGER = "ray._private.authentication.authentication_token_setup"


class _DropMessage(logging.Filter):
    def __init__(self, start: str) -> None:
        super().__init__()
        self.start = start

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(self.start)


def setup_output(quiet: bool = False, verbose: bool = False, private_ray: bool = True) -> None:
    """Log levels for pcpg and its libraries, before any of them is imported.

    Default: pcpg's warnings (one line each, ``pcpg: ...``) and errors; library INFO chatter
    (MLflow's schema migration, alembic) hidden. ``quiet``: errors only. ``verbose``: INFO from
    pcpg and MLflow. A private Ray keeps token authentication, named explicitly so Ray does not
    announce its default; a joined cluster keeps whatever it uses.
    """
    level = logging.ERROR if quiet else logging.INFO if verbose else logging.WARNING
    handler = logging.StreamHandler()  # stderr
    handler.setFormatter(logging.Formatter("pcpg: %(message)s"))
    pcpg = logging.getLogger("pcpg_dist")
    pcpg.handlers[:] = [handler]
    pcpg.setLevel(level)
    pcpg.propagate = False
    library = logging.getLevelName(max(level, logging.WARNING) if not verbose else logging.INFO)
    os.environ.setdefault(
        "MLFLOW_LOGGING_LEVEL", library
    )  # read when mlflow configures its loggers
    for name in ("mlflow", "alembic"):
        logging.getLogger(name).setLevel(
            os.environ["MLFLOW_LOGGING_LEVEL"] if name == "mlflow" else library
        )
    if private_ray or _has_ray_token():  # a joined cluster: token mode where a token is at hand, as
        os.environ.setdefault("RAY_AUTH_MODE", "token")  # `ray start` does (ray.init does not)
    for name, start in (
        (_RAY_AUTH_LOGGER, _RAY_TOKEN_NOTICE),
        # ray:// (Ray Client) connects from a thread, where Ray cannot set its handler
        ("ray._private.worker", "SIGTERM handler is not set because current thread"),
    ):
        logger = logging.getLogger(name)
        if not any(isinstance(f, _DropMessage) and f.start == start for f in logger.filters):
            logger.addFilter(_DropMessage(start))


def _has_ray_token() -> bool:
    """Whether this machine has a Ray token for a driver (the variables Ray reads, or its file)."""
    path = os.environ.get("RAY_AUTH_TOKEN_PATH") or os.path.expanduser("~/.ray/auth_token")
    return bool(os.environ.get("RAY_AUTH_TOKEN")) or os.path.isfile(path)


@contextmanager
def progress_bar(
    description: str, total: int, enabled: bool = True
) -> Iterator[Callable[..., None]]:
    """Yield ``advance(n=1, description=None)`` (a new description says e.g. what tasks wait for);
    shows a bar on a terminal, a final line otherwise."""
    if not enabled:
        yield lambda n=1, description=None: None
        return
    if not console.is_terminal:  # a log file: plain lines as the work goes, not one at the end
        yield from _lines(description, total)
        return
    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        transient=False,
    ) as progress:
        task = progress.add_task(description, total=total)

        def advance(n: float = 1, description: str | None = None) -> None:
            progress.update(
                task, advance=n, **({"description": description} if description else {})
            )

        yield advance


#: seconds between two progress lines when stderr is not a terminal (a log file, a pipe)
LINE_SECONDS = float(os.environ.get("PCPG_PROGRESS_SECONDS", "30"))


def _lines(description: str, total: int) -> Iterator[Callable[..., None]]:
    """Progress for a log file: a line when the work starts, one every :data:`LINE_SECONDS`
    while it goes on, and one when it ends, each with the count and the time so far."""
    import time

    start = last = time.monotonic()
    state = {"done": 0.0, "description": description, "said": -1.0}

    def say() -> None:
        state["said"] = state["done"]
        took = time.monotonic() - start
        console.print(
            f"{state['description']}: {state['done']:.0f}/{total} ({took:.0f} s)",
            markup=False,
            highlight=False,
        )

    say()

    def advance(n: float = 1, description: str | None = None) -> None:
        nonlocal last
        state["done"] += n
        if description:
            state["description"] = description
        if time.monotonic() - last >= LINE_SECONDS:
            last = time.monotonic()
            say()

    yield advance
    if state["done"] != state["said"]:
        say()
