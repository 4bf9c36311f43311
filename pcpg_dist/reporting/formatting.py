"""How every number on a report page is written, decided per column (a column never mixes "7.000"
and "11"), and the tables of the page model built from the CSV tables with those rules."""

from __future__ import annotations

import math
import re

import numpy as np
import pandas as pd

from pcpg_dist.reporting.report_data import (
    HEADERS,
    LEADING,
    MAX_ROWS,
    METHOD_NAMES,
    Table,
    _cell_number,
    is_matrix_column,
)

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
