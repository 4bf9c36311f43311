"""The project's own error types: every failure a user can cause is one of these.

The CLI prints ``str(error)`` on one line and exits with code 2; nothing else is caught, so a
raw traceback always means a bug in pcpg-dist, never a mistake in the user's input.
"""

from __future__ import annotations

import contextlib


def first_line(error: BaseException, limit: int = 200) -> str:
    """An exception's text for a one-line message: its first line, control characters escaped
    (thrift's raw bytes in Arrow's errors), cut to ``limit``; the type's name if it has no text."""
    lines = str(error).strip().splitlines()
    text = "".join(
        c if c.isprintable() else repr(c)[1:-1] for c in (lines[0] if lines else "")[:limit]
    )
    return text or type(error).__name__


def shorten(text: str, limit: int = 200) -> str:
    """``text`` with every word (run of non-spaces) longer than ``limit`` cut to its head, ``…``
    and its tail, then each line cut in the middle beyond ``5 * limit``: a message that echoes a
    5,000-character value keeps its key, its file name and its hint, in a line one can read."""
    head, tail, most = limit * 2 // 3, limit // 3, 5 * limit

    def line_of(line: str) -> str:
        words = (w if len(w) <= limit else f"{w[:head]}…{w[-tail:]}" for w in line.split(" "))
        line = " ".join(words)
        return line if len(line) <= most else f"{line[: most - 3 * tail]} … {line[-2 * tail :]}"

    return "\n".join(line_of(line) for line in text.split("\n"))


class PcpgError(Exception):
    """Base of every error caused by user input (config, data, level files, services)."""


class ConfigError(PcpgError):
    """An experiment config is invalid: the message names the key, the value and what is allowed."""


class DataError(PcpgError):
    """A dataset, play log or model file is missing, corrupt or of the wrong shape."""


class LayoutError(PcpgError):
    """A level or layout file is malformed: the message names the file and the line."""


class TrainingError(PcpgError):
    """Training diverged (non-finite weights or loss): the message names the cell and the
    hyper-parameters to change; nothing trained by that run is published."""


class DomainError(PcpgError):
    """A domain broke its contract (docs/writing-a-domain.md): one of its methods raised, or
    returned what pcpg cannot use; the message names the domain, the method and what was wrong."""


class ServiceError(PcpgError):
    """A tracking server, Ray cluster or study storage cannot be reached or used."""


sigterm_received = False  # set by catch_sigterm's handler
_holding = 0  # how many signals_held blocks are open in the main thread
_held: int | None = None  # the signal that arrived inside one, raised when the last one ends


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill PID``, ``timeout``, a scheduler's stop), handled as Ctrl-C: every cleanup that
    an interrupt runs (MLflow run marked KILLED, locks released) runs for it too."""


def _interrupt(signum: int) -> KeyboardInterrupt:
    import signal

    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def catch_sigterm() -> None:
    """Turn SIGTERM into :class:`Terminated` in the main thread, and let :func:`signals_held` hold it
    and Ctrl-C back. Called again after ``ray.init``, whose core worker installs a handler that
    aborts with a C++ stack dump (exit 134). Ctrl-C keeps Python's own handler's meaning, and is
    left alone where it was not Python's (ignored in a background job, say)."""
    import signal
    import threading

    def on_signal(signum, frame):
        global sigterm_received, _held
        if signum == signal.SIGTERM:  # Ray turns an exception raised in its calls into a plain
            sigterm_received = True  # KeyboardInterrupt: the flag keeps which signal it was
        if _holding and _held is None:  # a second signal is not held: a hung database
            _held = signum  # must not make the command deaf to Ctrl-C
            return
        _held = None
        raise _interrupt(signum)

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, on_signal)
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            signal.signal(signal.SIGINT, on_signal)


@contextlib.contextmanager
def signals_held():
    """Hold SIGTERM and Ctrl-C until the block ends, then raise them; a second one while one is held
    is raised at once. For a write to a database: one interrupted inside its commit keeps the
    database's write lock in this process, so the cleanup that marks the run KILLED then waits on
    that lock and fails ("database is locked")."""
    global _holding, _held
    import threading

    if threading.current_thread() is not threading.main_thread():  # signals reach the main thread
        yield
        return
    _holding += 1
    try:
        yield
    finally:
        _holding -= 1
        if not _holding and _held is not None:
            signum, _held = _held, None
            raise _interrupt(signum)


def pcpg_error_in(e: BaseException) -> PcpgError | None:
    """The project's own error inside what Ray raised: a task's (Ray keeps it as the cause), a
    Ray Data block function's (Ray Data hands it back as its worker's traceback text only, a
    ``UserCodeException``: the last pcpg error line in it), or ``e`` itself; None if there is
    none."""
    import ray.exceptions

    if not isinstance(e, ray.exceptions.RayTaskError):
        return e if isinstance(e, PcpgError) else None
    return e.cause if isinstance(e.cause, PcpgError) else said_in_worker(str(e))


def said_in_worker(text: str) -> PcpgError | None:
    """The last pcpg error line of a worker's traceback text, as that error."""
    import re

    found = re.findall(r"pcpg_dist\.common\.errors\.(\w+): ([^\n]+)", text)
    kind = globals().get(found[-1][0]) if found else None
    if not (isinstance(kind, type) and issubclass(kind, PcpgError)):
        return None
    return kind(found[-1][1].strip())
