"""The report's data layer: the page model and the files read only from inside a run's summary
folder (numbers are formatted for the page by :mod:`pcpg_dist.reporting.formatting`).

Every function here takes a path it checks with :func:`inside` (a regular file below the summary
folder, reached without symlinks); nothing takes a path from a file's content.
"""

from __future__ import annotations

import base64
import contextlib
import contextvars
import os
import reprlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from pcpg_dist.common.errors import DataError
from pcpg_dist.common.files import read_json
from pcpg_dist.common.inputs import entries, input_file, input_folder

MAX_ROWS = 30  # rows of a table shown on the page; the file has them all
MAX_IMAGE_BYTES = 8_000_000  # a figure larger than this is not inlined (the file is named instead)

#: readable column headers; anything else shows with underscores as spaces
HEADERS = {
    "env": "environment",
    "pcpg": "PCPG",
    "no_clustering": "No Clustering",
    "no_clustering_own_subset": "No Clustering (own subset)",
    "majority": "majority class",
    "k": "cluster k",
    "c": "corrupted fraction c",
    "n": "trajectories",
    "pcpg_mean": "PCPG distance",
    "random": "random",
    "gap_to_ceiling": "gap to ceiling (ceiling − accuracy)",
    "fit_seconds": "fit seconds",
    "true_subsets": "on the true subsets",
    "baseline_mean": "No Clustering",
    "headline": "headline p",
}
#: columns shown first (after the row label) in a table, by file stem
LEADING = {"clustering": ("accuracy", "ceiling", "gap_to_ceiling")}
METHOD_NAMES = {
    "pcpg": "PCPG",
    "nc": "No Clustering",
    "no_clustering": "No Clustering",
    "no_clustering_own_subset": "No Clustering (own subset)",
    "majority": "majority class",
}


# ----------------------------------------------------------------------------- page model
@dataclass
class Table:
    name: str  # file stem, e.g. "cross_accuracy"
    headers: list[str]
    rows: list[list[str]]
    hidden_rows: int = 0
    file: str = ""


@dataclass
class Figure:
    file: str  # path relative to the summary folder
    uri: str  # data: URI ("" when too large to inline)
    alt: str


@dataclass
class Section:
    anchor: str
    title: str
    paper_ref: str = ""
    paper_says: str = ""
    ours: str = ""
    figure: Figure | None = None
    tables: list[Table] = field(default_factory=list)


@dataclass
class PaperRow:
    item: str
    anchor: str
    paper: str
    ours: str


# ----------------------------------------------------------------------------- safe reading
def inside(path: Path, root: Path) -> bool:
    """Whether the report reads ``path``: a regular file below ``root``; False where there is no
    such file or the name (from a run's files) leads out of ``root``. The input policy applies
    (:mod:`pcpg_dist.common.inputs`): a link out of the run or a special file (a FIFO as a
    summary CSV) is one line, never read and never skipped in silence."""
    try:
        rel = Path(os.path.abspath(path)).relative_to(os.path.abspath(root))
    except ValueError:
        return False  # a name that leaves the run: never read
    if ".." in rel.parts or not (path.exists() or path.is_symlink()):
        return False
    input_file(path, "summary file", folder=root)
    return True


def files_in(folder: Path, root: Path, suffix: str) -> list[Path]:
    """The ``suffix`` files of one of the run's folders (an environment's), checked."""
    if not inside_folder(folder, root):
        return []
    return [p for p in entries(folder, "summary file", suffixes=[suffix]) if inside(p, root)]


def inside_folder(folder: Path, root: Path) -> bool:
    """Whether ``folder`` is one of the run's folders (a link out of the run is one line)."""
    if not (folder.exists() or folder.is_symlink()):
        return False
    input_folder(folder, "summary folder", folder=root)
    return True


def _as_float(v) -> float | None:
    """A JSON number as a float; None for anything else (text, lists, true, an integer beyond
    float's range)."""
    if not isinstance(v, int | float) or isinstance(v, bool):
        return None
    try:
        return float(v)
    except OverflowError:
        return None


#: the fields of run.json the report and reproduce use, when present: (type, what it holds)
RUN_FIELDS = {
    "config": (dict, "an object"),
    "provenance": (dict, "an object"),
    "computed": (dict, "an object of counts"),
    "stage_seconds": (dict, "an object of seconds"),
    "cached_stages": (list, "a list of stage names"),
    "batch_points": (int, "a count of points"),
}


def read_run(path: Path) -> dict:
    """``run.json``, its typed fields checked (one line naming the field when one is wrong)."""
    run = read_json(path)
    for key, (kind, what) in RUN_FIELDS.items():
        if key in run and not isinstance(run[key], kind):
            raise DataError(f"{path}: {key!r} is {reprlib.repr(run[key])}; expected {what}")
    for stage, n in run.get("computed", {}).items():
        if not (isinstance(n, int) and not isinstance(n, bool) and n >= 0):
            raise DataError(
                f"{path}: computed {reprlib.repr(stage)} is {reprlib.repr(n)}; expected a count "
                "(an integer >= 0)"
            )
    for stage, secs in run.get("stage_seconds", {}).items():
        if _as_float(secs) is None:
            raise DataError(
                f"{path}: stage_seconds {reprlib.repr(stage)} is {reprlib.repr(secs)}; expected "
                "a number of seconds"
            )
    for stage in run.get("cached_stages", []):
        if not isinstance(stage, str):
            raise DataError(
                f"{path}: cached_stages holds {reprlib.repr(stage)}; expected stage names"
            )
    return run


ACCURACY_AT_P = "pcpg/accuracy/p"  # metric names pcpg/accuracy/p<p>: the p is read from the name


def read_metrics(path: Path) -> dict[str, float | None]:
    """``metrics.json``: metric name to a number (null for a metric that could not be computed)."""
    metrics = {}
    for key, value in read_json(path).items():
        metrics[key] = None if value is None else _as_float(value)
        if value is not None and metrics[key] is None:
            raise DataError(
                f"{path}: metric {reprlib.repr(key)} is {reprlib.repr(value)}; expected a number "
                "(or null)"
            )
        if key.startswith(ACCURACY_AT_P) and key.count("/") == 2:
            try:
                float(key.removeprefix(ACCURACY_AT_P))
            except ValueError:
                raise DataError(
                    f"{path}: metric {reprlib.repr(key)}: the text after {ACCURACY_AT_P!r} should "
                    "be a number (the p)"
                ) from None
    return metrics


@dataclass(frozen=True)
class TableSpec:
    """What the report's code relies on in one kind of summary table."""

    columns: tuple[str, ...] = ()  # required, any type
    numbers: tuple[str, ...] = ()  # required, numbers (an empty cell is allowed: a missing value)
    number_prefix: str = ""  # more numeric columns: every ``<prefix><digits>`` (R1, R2, ...)
    unique: tuple[str, ...] = ()  # columns that together name one row


#: tables the report computes with (by file stem); any other table is only shown, cell by cell
TABLE_SPECS = {
    "accuracy": TableSpec(("method",), ("p", "mean", "std"), unique=("method", "p")),
    "rollout_length": TableSpec(("method",), ("p", "mean")),
    "subset_length": TableSpec(("method",), ("p", "mean")),
    "corruption_accuracy": TableSpec(numbers=("c", "mean", "std")),
    "corruption_reward": TableSpec(numbers=("c",), number_prefix="R"),
    "cluster_style": TableSpec(numbers=("k", "style"), unique=("k",)),
}
#: matrices written with their row labels as the first, unnamed column (any such table is one)
MATRICES = ("cross_accuracy", "cross_accuracy_std", "correlation", "correlation_std")


def is_matrix_column(name) -> bool:
    return str(name).startswith("Unnamed") or str(name) == "index"


def _cell_repr(v) -> str:
    return reprlib.repr(v.item() if hasattr(v, "item") else v)  # 1.0, not np.float64(1.0)


def _cell_number(v) -> float | None:
    """A table cell as a float (an empty cell is NaN); None for text, true/false or an integer
    beyond float's range."""
    if pd.api.types.is_bool(v):
        return None
    try:
        return float(v)
    except (TypeError, ValueError, OverflowError):
        return None


def _check_numbers(df: pd.DataFrame, col: str, path: Path) -> None:
    column = df[col]
    if pd.api.types.is_numeric_dtype(column) and not pd.api.types.is_bool_dtype(column):
        df[col] = column.astype(float)  # parsed as numbers already: every cell is one
        return
    values = column.map(_cell_number)
    bad = values.isna() & df[col].notna()
    if bad.any():
        i = int(bad.to_numpy().argmax())
        raise DataError(
            f"{path}: column {reprlib.repr(str(col))}, line {i + 2}: {_cell_repr(df[col].iloc[i])} "
            "is not a number"
        )
    df[col] = values.astype(float)


def _check_unique(df: pd.DataFrame, cols: list, path: Path) -> None:
    repeated = df.duplicated(subset=cols)
    if repeated.any():
        i = int(repeated.to_numpy().argmax())
        row = ", ".join(
            f"{'label' if is_matrix_column(c) else c} {_cell_repr(df[c].iloc[i])}" for c in cols
        )
        raise DataError(f"{path}: line {i + 2} repeats the row for {row}; each may appear once")


def check_table(df: pd.DataFrame, path: Path) -> pd.DataFrame:
    """``df`` (read from ``path``) checked against what the report computes with; one line naming
    the file, column and line of the first problem."""
    cols = [str(c) for c in df.columns]
    if path.stem in MATRICES or (cols and is_matrix_column(cols[0])):
        if len(cols) < 2:
            raise DataError(
                f"{path}: a matrix needs row labels and at least one column; found {reprlib.repr(cols)}"
            )
        _check_unique(df, [df.columns[0]], path)
        for col in df.columns[1:]:
            _check_numbers(df, col, path)
        return df
    spec = TABLE_SPECS.get(path.stem, TableSpec())
    missing = [c for c in spec.columns + spec.numbers if c not in cols]
    if missing:
        raise DataError(
            f"{path}: no column {missing[0]!r} (found {reprlib.repr(cols)}); this table needs "
            f"{', '.join(spec.columns + spec.numbers)}"
        )
    prefixed = [
        c
        for c in cols
        if spec.number_prefix
        and c.startswith(spec.number_prefix)
        and c.removeprefix(spec.number_prefix).isdigit()
    ]
    for col in [*spec.numbers, *prefixed]:
        _check_numbers(df, col, path)
    if spec.unique:
        _check_unique(df, list(spec.unique), path)
    return df


_tables: contextvars.ContextVar[dict | None] = contextvars.ContextVar("tables", default=None)


@contextlib.contextmanager
def reading_once() -> Iterator[None]:
    """Within the block, :func:`read_csv` reads and checks each file once (the page model reads
    an environment's tables for its sections and again for the paper comparison)."""
    token = _tables.set({})
    try:
        yield
    finally:
        _tables.reset(token)


def read_csv(path: Path) -> pd.DataFrame | None:
    """A summary table, checked by :func:`check_table`; None when the file has no columns at all.
    Inside :func:`reading_once`, a file already read comes back as a copy of the first reading."""
    seen = _tables.get()
    if seen is None:
        return _read_checked(path)
    key = str(path)
    if key not in seen:
        seen[key] = _read_checked(path)
    return None if seen[key] is None else seen[key].copy()


def _read_checked(path: Path) -> pd.DataFrame | None:
    try:
        df = pd.read_csv(path)
    except pd.errors.EmptyDataError:
        return None  # an empty table (e.g. no rollouts for this setting) has nothing to show
    except (OSError, ValueError, pd.errors.ParserError) as e:
        raise DataError(f"{path}: unreadable table ({' '.join(str(e).split())[:300]})") from None
    return check_table(df, path)


def figure_of(path: Path, root: Path, alt: str) -> Figure | None:
    if not inside(path, root) or path.suffix != ".png":
        return None
    data = path.read_bytes()
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        return None  # only real PNG images are inlined
    uri = (
        ""
        if len(data) > MAX_IMAGE_BYTES
        else "data:image/png;base64," + base64.b64encode(data).decode()
    )
    return Figure(str(path.relative_to(root)), uri, alt)
