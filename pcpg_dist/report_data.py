"""The report's data layer: files read only from inside a run's summary folder, and tables
formatted for the page (real headers, mean ± std merged, matrices labelled).

Every function here takes a path it checks with :func:`inside` (a regular file below the summary
folder, reached without symlinks); nothing takes a path from a file's content.
"""

from __future__ import annotations

import base64
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from pcpg_dist.errors import DataError

MAX_ROWS = 30  # rows of a table shown on the page; the file has them all
MAX_IMAGE_BYTES = 8_000_000  # a figure larger than this is not inlined (the file is named instead)

#: readable column headers; anything else shows with underscores as spaces
HEADERS = {"env": "environment", "pcpg": "PCPG", "no_clustering": "No Clustering",
           "no_clustering_own_subset": "No Clustering (own subset)", "majority": "majority class",
           "k": "cluster k", "c": "corrupted fraction c", "n": "trajectories",
           "pcpg_mean": "PCPG distance", "random": "random", "gap_to_ceiling": "gap to ceiling",
           "fit_seconds": "fit seconds", "true_subsets": "on the true subsets",
           "baseline_mean": "No Clustering", "headline": "headline p"}
METHOD_NAMES = {"pcpg": "PCPG", "nc": "No Clustering", "no_clustering": "No Clustering",
                "no_clustering_own_subset": "No Clustering (own subset)", "majority": "majority class"}


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


def read_json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise DataError(f"{path}: unreadable ({e})") from None
    if not isinstance(data, dict):
        raise DataError(f"{path}: expected a JSON object, found {type(data).__name__}")
    return data


def read_csv(path: Path) -> pd.DataFrame | None:
    try:
        return pd.read_csv(path)
    except pd.errors.EmptyDataError:
        return None  # an empty table (e.g. no rollouts for this setting) has nothing to show
    except (OSError, ValueError, pd.errors.ParserError) as e:
        raise DataError(f"{path}: unreadable table ({e})") from None


def figure_of(path: Path, root: Path, alt: str) -> Figure | None:
    if not inside(path, root) or path.suffix != ".png":
        return None
    data = path.read_bytes()
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        return None  # only real PNG images are inlined
    uri = "" if len(data) > MAX_IMAGE_BYTES else "data:image/png;base64," + base64.b64encode(data).decode()
    return Figure(str(path.relative_to(root)), uri, alt)


# ----------------------------------------------------------------------------- formatting
def fmt(v, digits: int = 3) -> str:
    """A table cell: floats to ``digits`` decimals (4 significant when large), NaN as a dash."""
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "—"
        if v.is_integer() and abs(v) < 1e6:
            return f"{v:.{digits}f}" if abs(v) < 10 else f"{v:.0f}"
        return f"{v:.{digits}f}" if abs(v) < 100 else f"{v:.4g}" if abs(v) < 1e4 else f"{v:.3e}"
    return str(v)


def _pm(mean, std) -> str:
    if std is None or (isinstance(std, float) and math.isnan(std)):
        return fmt(mean)
    return f"{fmt(mean)} ± {fmt(std)}"


def _header(col: str) -> str:
    return HEADERS.get(col, col.replace("_", " "))


def _cell(col: str, v) -> str:
    if col == "method" and isinstance(v, str):
        return METHOD_NAMES.get(v, v)
    if hasattr(v, "item"):
        v = v.item()
    if col in ("p", "c", "reward_p") and isinstance(v, float) and not math.isnan(v):
        return f"{v:g}"  # the values the config names, as written there
    return fmt(v)


def table_of(df: pd.DataFrame, name: str, file: str = "", std: pd.DataFrame | None = None) -> Table:
    """A page table: real headers, ``X`` and ``X_std`` (or ``mean``/``std``) merged as mean ± std."""
    df = df.copy()
    first = str(df.columns[0])
    if first.startswith("Unnamed") or first == "index":  # a matrix written with its index
        df = df.set_index(first)
        if std is not None and str(std.columns[0]).startswith("Unnamed"):
            std = std.set_index(std.columns[0])
        rows = []
        for label, row in df.iterrows():
            cells = [f"π {label}"]
            for col in df.columns:
                s = std.loc[label, col] if std is not None and col in std.columns else None
                cells.append(_pm(float(row[col]), None if s is None else float(s)))
            rows.append(cells)
        return Table(name, ["model π_k \\ subset"] + [f"H {c}" for c in df.columns], rows[:MAX_ROWS],
                     max(0, len(rows) - MAX_ROWS), file)
    prefix = _common_prefix([str(c) for c in df.columns])
    if prefix:  # e.g. clustering/ari, clustering/nmi: the table's caption already says clustering
        df = df.rename(columns=lambda c: str(c).removeprefix(prefix))
    cols = [str(c) for c in df.columns]
    pairs: dict[str, str] = {}
    for c in cols:
        for mean, sd in ((c, f"{c}_std"), (c, c[: -len("_mean")] + "_std" if c.endswith("_mean") else "")):
            if sd in cols and c not in pairs.values():
                pairs[mean] = sd
        if c == "mean" and "std" in cols:
            pairs["mean"] = "std"
    shown = [c for c in cols if c not in pairs.values()]
    headers = []
    for c in shown:
        base = c[: -len("_mean")] if c.endswith("_mean") and c in pairs else c
        headers.append(_header(base) + (" ± std" if c in pairs else ""))
    rows = []
    for rec in df.to_dict("records"):
        rows.append([_pm(rec[c], rec[pairs[c]]) if c in pairs else _cell(c, rec[c]) for c in shown])
    if len(headers) > 8 and len(rows) <= 4:  # few rows of many columns (a metrics row per env): turn
        # it on its side, so it reads down the page instead of overflowing it
        rows = [[h, *(r[i] for r in rows)] for i, h in enumerate(headers) if i > 0]
        headers = [headers[0]] + [r0[0] for r0 in
                                  [[_cell(shown[0], v)] for v in df[shown[0]]]]
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


