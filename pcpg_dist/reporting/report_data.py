"""The report's data layer: files read only from inside a run's summary folder, and tables
formatted for the page (real headers, mean ± std merged, matrices labelled).

Every function here takes a path it checks with :func:`inside` (a regular file below the summary
folder, reached without symlinks); nothing takes a path from a file's content.
"""

from __future__ import annotations

import base64
import math
import re
import reprlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from pcpg_dist.common.errors import DataError
from pcpg_dist.common.files import read_json

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
    """A regular file below ``root`` reached without symlinks (the only files a report reads)."""
    try:
        if path.is_symlink() or not path.is_file():
            return False
        resolved = path.resolve(strict=True)
        rel = resolved.relative_to(root.resolve(strict=True))
    except (OSError, ValueError):
        return False
    return not any(part.startswith("..") for part in rel.parts)


def files_in(folder: Path, root: Path, suffix: str) -> list[Path]:
    if folder.is_symlink() or not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.suffix == suffix and inside(p, root))


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
    values = df[col].map(_cell_number)
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


def read_csv(path: Path) -> pd.DataFrame | None:
    """A summary table, checked by :func:`check_table`; None when the file has no columns at all."""
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


# ----------------------------------------------------------------------------- formatting
# One rule for every number on the page, decided per column (a column never mixes "7.000" and
# "11"): counts as integers, lengths and rewards to 1 decimal, everything else (accuracies,
# fractions, correlations, scores, seconds) to 3 decimals; a std takes its mean's decimals.
FRACTION, LENGTH, COUNT = 3, 1, 0

#: tables whose measured columns are lengths or rewards (numbers of steps, returns): 1 decimal
LENGTH_TABLES = ("rollout_length", "subset_length", "reward_distance", "corruption_reward")
_LENGTH_NAME = re.compile(r"length|return|reward|optimal")
_COUNT_NAME = re.compile(
    r"(^|[_/ ])(n|k|count|seeds?|styles?|epochs?|rounds?|iterations?|trajectories|clusters)"
    r"([_/ ]|$)|_run$|_used$"
)
#: axis columns shown as the config writes them (0.25, 1), never padded
AS_WRITTEN = ("p", "c", "reward_p")


def fmt(v, digits: int = FRACTION) -> str:
    """One number: ``digits`` decimals (an integer as it is), NaN and None as a dash."""
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if hasattr(v, "item"):
        v = v.item()
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "—"
        if abs(v) >= 1e6:
            return f"{v:.3e}"
        return f"{v:.{digits}f}"
    return str(v)


def digits_of(values, name: str = "", table: str = "") -> int:
    """The decimals of a column: :data:`COUNT` for counts (integers, or whole numbers in a column
    named like a count or above 1), :data:`LENGTH` for lengths and rewards, else :data:`FRACTION`."""
    nums = [float(v) for v in values if _cell_number(v) is not None and not math.isnan(float(v))]
    if not nums:
        return FRACTION
    name = str(name).lower()
    if table in LENGTH_TABLES or _LENGTH_NAME.search(name):
        if (
            all(isinstance(v, int | np.integer) and not isinstance(v, bool) for v in values)
            and name != "mean"
        ):
            return COUNT  # an index (k, style) in a lengths table
        return LENGTH
    if all(v.is_integer() for v in nums) and (
        _COUNT_NAME.search(name) or max(abs(v) for v in nums) > 1
    ):
        return COUNT
    return FRACTION


def _pm(mean, std, digits: int = FRACTION) -> str:
    if digits == COUNT:
        digits = LENGTH if std is not None else COUNT  # a mean of counts over seeds: 1 decimal
    if std is None or (isinstance(std, float) and math.isnan(std)):
        return fmt(mean, digits)
    return f"{fmt(mean, digits)} ± {fmt(std, digits)}"


def _header(col: str) -> str:
    return HEADERS.get(col, col.replace("_", " "))


def _cell(col: str, v, digits: int = FRACTION) -> str:
    if col == "method" and isinstance(v, str):
        return METHOD_NAMES.get(v, v)
    if hasattr(v, "item"):
        v = v.item()
    if col in AS_WRITTEN and isinstance(v, float) and not math.isnan(v):
        return f"{v:g}"  # the values the config names, as written there
    if col == "k" and isinstance(v, int | float) and not isinstance(v, bool) and v < 0:
        return "—"  # No Clustering has no cluster (its rows carry k = -1)
    if digits == COUNT and isinstance(v, float) and v.is_integer():
        return str(int(v))
    return fmt(v, digits)


def table_of(df: pd.DataFrame, name: str, file: str = "", std: pd.DataFrame | None = None) -> Table:
    """A page table: real headers, ``X`` and ``X_std`` (or ``mean``/``std``) merged as mean ± std."""
    df = df.copy()
    first = str(df.columns[0])
    if is_matrix_column(first):  # a matrix written with its index
        df = df.set_index(first)
        if std is not None and is_matrix_column(std.columns[0]):
            std = std.set_index(std.columns[0])
        digits = digits_of(df.to_numpy().ravel(), table=name)
        rows = []
        for label, row in df.iterrows():
            cells = [f"π {label}"]
            for col in df.columns:
                known = std is not None and col in std.columns and label in std.index
                s = std.loc[label, col] if known else None
                cells.append(_pm(float(row[col]), None if s is None else float(s), digits))
            rows.append(cells)
        return Table(
            name,
            ["model π_k \\ subset"] + [f"H {c}" for c in df.columns],
            rows[:MAX_ROWS],
            max(0, len(rows) - MAX_ROWS),
            file,
        )
    prefix = _common_prefix([str(c) for c in df.columns])
    if prefix:  # e.g. clustering/ari, clustering/nmi: the table's caption already says clustering
        df = df.rename(columns=lambda c: str(c).removeprefix(prefix))
    lead = [c for c in LEADING.get(name, ()) if c in df.columns]
    if lead:  # the columns a reader looks for first, then the diagnostics
        df = df[[df.columns[0], *lead, *(c for c in df.columns[1:] if c not in lead)]]
    cols = [str(c) for c in df.columns]
    pairs: dict[str, str] = {}
    for c in cols:
        for mean, sd in (
            (c, f"{c}_std"),
            (c, c[: -len("_mean")] + "_std" if c.endswith("_mean") else ""),
        ):
            if sd in cols and c not in pairs.values():
                pairs[mean] = sd
        if c == "mean" and "std" in cols:
            pairs["mean"] = "std"
    shown = [c for c in cols if c not in pairs.values()]
    headers = []
    for c in shown:
        base = c[: -len("_mean")] if c.endswith("_mean") and c in pairs else c
        headers.append(_header(base) + (" ± std" if c in pairs else ""))
    digits = {c: digits_of(df[c].tolist(), c, name) for c in shown}
    rows = []
    for rec in df.to_dict("records"):
        rows.append(
            [
                _pm(rec[c], rec[pairs[c]], digits[c]) if c in pairs else _cell(c, rec[c], digits[c])
                for c in shown
            ]
        )
    if (
        len(headers) > 8 and len(rows) <= 4
    ):  # few rows of many columns (a metrics row per env): turn
        # it on its side, so it reads down the page instead of overflowing it
        rows = [[h, *(r[i] for r in rows)] for i, h in enumerate(headers) if i > 0]
        headers = [headers[0]] + [r0[0] for r0 in [[_cell(shown[0], v)] for v in df[shown[0]]]]
    return Table(name, headers, rows[:MAX_ROWS], max(0, len(rows) - MAX_ROWS), file)


def _common_prefix(cols: list[str]) -> str:
    """``section/`` when most columns share it (the first column, e.g. ``env``, may not)."""
    heads = [c.split("/", 1)[0] + "/" for c in cols if "/" in c]
    if len(heads) < 2 or len(set(heads)) != 1:
        return ""
    return heads[0]


def accuracy_pivot(df: pd.DataFrame) -> pd.DataFrame:
    """One environment's long accuracy table as p rows (increasing) by method columns."""
    wide = pd.DataFrame({"p": sorted(df.p.unique())})
    for method in dict.fromkeys(df.method):
        d = df[df.method == method].set_index("p")
        wide[method] = wide.p.map(d["mean"])
        if method not in ("random", "majority"):
            wide[f"{method}_std"] = wide.p.map(d["std"])
    return wide
