"""An Optuna journal file that refuses a file which is not a journal, before anything is written.

Imported by :func:`pcpg_dist.orchestration.tuning.storage.open_storage` only when a journal is
opened, so that importing ``pcpg_dist.orchestration.tuning`` (every Ray worker running a trial
does) does not import Optuna's storages.
"""

from __future__ import annotations

import itertools
import json
import reprlib
from collections.abc import Generator
from typing import Any

from optuna.storages.journal import JournalFileBackend
from optuna.storages.journal._storage import JournalOperation

from pcpg_dist.common.errors import DataError

_JOURNAL_OPS = frozenset(int(op) for op in JournalOperation)  # Optuna's replay asserts on any other
_REPR = reprlib.Repr()
_REPR.maxstring = _REPR.maxother = 80


def short(value: Any) -> str:
    """A value from a file or the command line, cut to keep its message one short line."""
    return _REPR.repr(value)


def _log_problem(log: Any) -> str | None:
    """What makes one parsed journal line something other than an Optuna journal operation."""
    if not isinstance(log, dict):
        return f"{short(log)} is not a JSON object"
    op = log.get("op_code")
    if type(op) is not int or op not in _JOURNAL_OPS:
        return f"op_code {short(op)} is not one of Optuna's journal operations (0..{max(_JOURNAL_OPS)})"
    return None


def _line_problem(line: bytes) -> str:
    """Why a journal line cannot be read (it is shown in the error, cut to one short line)."""
    if not line.endswith(b"\n"):
        return "cut off, no newline at its end (a driver stopped while writing it? delete that line to go on)"
    try:
        log = json.loads(line)
    except json.JSONDecodeError as e:
        return f"not JSON ({e.msg}): {short(line.decode(errors='replace').rstrip())}"
    except (ValueError, RecursionError) as e:  # not UTF-8; nested too deep
        return f"not JSON ({type(e).__name__}): {short(line)}"
    return _log_problem(log) or f"{short(log)}"


class CheckedJournalBackend(JournalFileBackend):
    """Optuna's journal file, refusing a file that is not a journal before anything is written.

    Optuna replays any file it is given: another file's lines end in a traceback deep in the
    replay (``KeyError``, ``TypeError``, an ``assert``), and a last line that does not parse is
    skipped as "being written", after which the journal's own lines are appended to the file.
    Each line is checked as Optuna reads it (a large journal is not read twice); ``line`` is the
    number of the last line handed to Optuna.
    """

    def __init__(self, file_path: str) -> None:
        super().__init__(file_path)
        self.line = 0

    def read_logs(self, log_number_from: int) -> Generator[dict[str, Any], None, None]:
        self.line = log_number_from
        logs = super().read_logs(log_number_from)
        while True:
            try:
                log = next(logs)
            except StopIteration:
                return
            except (ValueError, RecursionError):
                # Optuna raises for a line that is not JSON when it reaches the line after it
                # (RecursionError: on the line itself); either way the next line is the bad one
                raise self.not_a_journal(self.line + 1) from None
            self.line += 1
            problem = _log_problem(log)
            if problem is not None:
                raise self.not_a_journal(self.line, problem)
            yield log

    def check_read_to_end(self) -> None:
        """Refuse a last line that Optuna skipped (not JSON, or cut off): the next append would
        join it and ruin the file."""
        lines, last = 0, b"\n"
        with open(self._file_path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                lines, last = lines + chunk.count(b"\n"), chunk[-1:]
        if last != b"\n":  # a last line without its newline
            lines += 1
        if lines > self.line:
            raise self.not_a_journal(self.line + 1)

    def not_a_journal(self, number: int, problem: str | None = None) -> DataError:
        """The one-line error for line ``number`` (1-based); without ``problem``, the line is read
        again to say what is wrong with it."""
        if problem is None:
            with open(self._file_path, "rb") as f:
                line = next(itertools.islice(f, number - 1, None), b"")
            problem = _line_problem(line)
        return DataError(
            f"cannot open the Optuna journal {self._file_path}: not an Optuna journal "
            f"(line {number}: {problem}); give a new file or another --optuna-storage"
        )
