"""Reading a sweep's output folder: ``sweep.json`` (checked field by field), ``summary.csv`` (one row
per point), and the headline metrics a sweep compares across its points."""

from __future__ import annotations

import re
import reprlib
from pathlib import Path
from typing import Any

from pcpg_dist.common.errors import DataError

STD = "/std"


SWEEP_JSON = (
    "sweep.json"  # the sweep-level record beside summary.csv: axes, fixed overrides, figures
)


SWEEP_FORMAT = 1


def ps_of(keys) -> list[str]:
    """The p values of ``pcpg/accuracy/p…`` among ``keys``, as written, largest first."""
    return sorted(
        {k.rsplit("/p", 1)[1] for k in keys if re.fullmatch(r"pcpg/accuracy/p[0-9.]+", k)},
        key=float,
        reverse=True,
    )


def headline_keys(metrics: dict[str, float]) -> list[str]:
    """What a sweep compares: clustering quality (with labels: accuracy, ceiling, gap; without:
    the label-free stability, what a user comparing k has), PCPG and No Clustering at every p and
    PCPG's lead."""
    keys = [
        k
        for k in (
            "clustering/accuracy",
            "clustering/ceiling",
            "clustering/gap_to_ceiling",
            "clustering/stability",
            "cross/diagonal_mean",
        )
        if k in metrics
    ]
    for p in ps_of(metrics):
        keys += [f"pcpg/accuracy/p{p}", f"baseline/accuracy/p{p}", f"pcpg_lead/p{p}"]
    return keys


def headline(metrics: dict[str, float]) -> dict[str, float]:
    """The headline metrics of one point and their std over seeds (``key/std``) where logged."""
    out: dict[str, float] = {}
    for k in headline_keys(metrics):
        if k.startswith("pcpg_lead/"):
            p = k.split("/p", 1)[1]
            a, b = metrics.get(f"pcpg/accuracy/p{p}"), metrics.get(f"baseline/accuracy/p{p}")
            if a is not None and b is not None:
                out[k] = a - b
            continue
        out[k] = metrics[k]
        if k + STD in metrics:
            out[k + STD] = metrics[k + STD]
    return out


def read_sweep_record(folder: Path) -> dict[str, Any]:
    """``sweep.json`` of a sweep folder, its fields checked (one line naming the file and field)."""
    from pcpg_dist.common.files import read_json

    path = Path(folder) / SWEEP_JSON
    if not path.is_file():
        report = Path(folder) / "report.html"
        older = f"; its report, as that sweep wrote it, is {report}" if report.is_file() else ""
        raise DataError(
            f"{folder}: no {SWEEP_JSON}, so not a sweep folder written by this pcpg{older} (rerunning the "
            "same pcpg sweep command writes it; finished units come from the cache)"
        )
    record = read_json(path)
    checks = {"name": str, "description": str, "axes": dict, "fixed": dict, "figures": list}
    for key, kind in checks.items():
        if not isinstance(record.get(key), kind):
            raise DataError(
                f"{path}: {key!r} is {reprlib.repr(record.get(key))}; expected {kind.__name__}"
            )
    for axis, values in record["axes"].items():
        if not isinstance(values, list):
            raise DataError(
                f"{path}: axis {reprlib.repr(axis)} holds {reprlib.repr(values)}; expected a list"
            )
    for name in record[
        "figures"
    ]:  # plain file names beside sweep.json: a figure never comes from elsewhere
        if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._=-]*\.png", name):
            raise DataError(
                f"{path}: figure {reprlib.repr(name)} is not a PNG file name of this folder"
            )
    return record


def read_sweep_rows(path: Path, axes: dict[str, list]) -> list[dict[str, Any]]:
    """summary.csv's rows: axis values as written, every metric a float (blank: not measured)."""
    import csv

    try:
        with open(path, newline="") as f:
            table = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise DataError(f"{path}: unreadable ({e})") from None
    rows = []
    for i, raw in enumerate(table, start=2):
        row: dict[str, Any] = {}
        for col, value in raw.items():
            if col is None or value is None:
                raise DataError(f"{path}: line {i} has more or fewer cells than the header")
            if col in axes or col == "point" or value == "":
                row[col] = value
                continue
            try:
                row[col] = float(value)
            except ValueError:
                raise DataError(
                    f"{path}: line {i}, {col!r} is {reprlib.repr(value)}; expected a number"
                ) from None
        rows.append(row)
    return rows


def is_sweep_folder(path: Path) -> bool:
    """A `pcpg sweep` output folder (``<workdir>/<name>/sweep``), also one written before sweep.json."""
    return (path / "sweep.json").is_file() or (
        (path / "summary.csv").is_file() and (path / "points").is_dir()
    )
