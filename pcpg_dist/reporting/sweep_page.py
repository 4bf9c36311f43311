"""A sweep's page: ``report.html`` of a sweep folder (its points' headline metrics as mean ± std,
the best point, each point's report linked, the figures), styled like a run's report, and the
sweep-level files (figures, ``summary.csv``, ``sweep.json``, the page) written together."""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pcpg_dist.common.files import atomic_write_bytes
from pcpg_dist.reporting.jinja import jinja_environment
from pcpg_dist.reporting.paper_comparison import plain
from pcpg_dist.reporting.report_data import inside, read_run
from pcpg_dist.reporting.sweep_figures import draw_sweep
from pcpg_dist.reporting.sweep_files import (
    STD,
    SWEEP_FORMAT,
    SWEEP_JSON,
    read_sweep_record,
    read_sweep_rows,
)

if TYPE_CHECKING:
    from pcpg_dist.orchestration.sweep import SweepPlan

SWEEP_STD = "/std"


def sweep_metric_label(key: str) -> str:
    """A readable name for a sweep's headline metric (``pcpg/accuracy/p0.5`` -> ``PCPG, p=0.5``)."""
    fixed = {
        "clustering/accuracy": "clustering accuracy",
        "clustering/ceiling": "supervised ceiling",
        "clustering/gap_to_ceiling": "gap to the ceiling (ceiling − accuracy)",
        "clustering/stability": "clustering stability (no labels)",
        "cross/diagonal_mean": "cross-accuracy diagonal (Table 4)",
    }
    if key in fixed:
        return fixed[key]
    for prefix, label in (
        ("pcpg/accuracy/p", "PCPG"),
        ("baseline/accuracy/p", "No Clustering"),
        ("pcpg_lead/p", "PCPG lead over No Clustering"),
    ):
        if key.startswith(prefix):
            return f"{label}, p={key.removeprefix(prefix)}"
    return key.replace("_", " ")


def _sweep_columns(keys: list[str]) -> list[str]:
    """The metric columns in reading order: per p (largest first) PCPG, No Clustering and the lead,
    then clustering accuracy, ceiling, gap, stability and the cross-accuracy diagonal, then
    anything else."""
    ps = sorted(
        {k.removeprefix("pcpg/accuracy/p") for k in keys if k.startswith("pcpg/accuracy/p")},
        key=lambda p: -float(p) if p.replace(".", "", 1).isdigit() else 0,
    )
    order = [
        k for p in ps for k in (f"pcpg/accuracy/p{p}", f"baseline/accuracy/p{p}", f"pcpg_lead/p{p}")
    ]
    order += [
        "clustering/accuracy",
        "clustering/ceiling",
        "clustering/gap_to_ceiling",
        "clustering/stability",
        "cross/diagonal_mean",
    ]
    shown = [k for k in order if k in keys]
    return shown + [k for k in keys if k not in shown]


def _sweep_cell(row: dict, key: str) -> str:
    v = row.get(key)
    if not isinstance(v, float):
        return "—"
    signed = key.startswith("pcpg_lead/") or key == "clustering/gap_to_ceiling"
    text = "—" if math.isnan(v) else f"{v:+.3f}" if signed else f"{v:.3f}"
    sd = row.get(key + SWEEP_STD)
    return (
        f"{text} ± {sd:.3f}"
        if isinstance(sd, float) and not math.isnan(sd) and text != "—"
        else text
    )


@dataclass
class SweepPage:
    title: str
    description: str
    headline: list[str]
    headers: list[str]
    rows: list[dict]  # {"cells": [...], "report": relative link or "", "point": folder name}
    figures: list[tuple[str, list[dict]]]  # (axis, [{"title", "caption", "uri", "name"}])
    command: str
    provenance: list[tuple[str, str]]
    fixed: list[tuple[str, str]]


def _num(r, k):
    """A row's metric as a float, None where it is blank or NaN (not measured)."""
    v = r.get(k)
    return v if isinstance(v, float) and not math.isnan(v) else None


def _point_rows(
    folder: Path, out_dir: Path, rows: list[dict], axes: dict, metrics: list[str]
) -> tuple[list[dict], dict | None]:
    """The table rows (cells, link to the point's report) and the first point's ``run.json``, for
    the command and provenance of the whole sweep."""
    from pcpg_dist.common.errors import DataError

    points_dir = folder / "points"
    # a point's folder is one listed in points/ (never a path read from summary.csv)
    listed = (
        {p.name: p for p in points_dir.iterdir() if p.is_dir() and not p.is_symlink()}
        if points_dir.is_dir() and not points_dir.is_symlink()
        else {}
    )
    link_base = Path(os.path.relpath(folder.resolve(), out_dir.resolve()))
    shown, run = [], None
    for r in rows:
        point = listed.get(str(r.get("point", "")))
        report = ""
        if point is not None and inside(point / "report" / "report.html", folder):
            report = (link_base / "points" / point.name / "report" / "report.html").as_posix()
        if point is not None and run is None and inside(point / "summary" / "run.json", folder):
            try:
                run = read_run(point / "summary" / "run.json")
            except DataError:
                run = None
        shown.append(
            {
                "cells": [plain(r.get(a, "")) for a in axes] + [_sweep_cell(r, k) for k in metrics],
                "report": report,
                "point": str(r.get("point", "")),
            }
        )
    return shown, run


def _sweep_headline(rows: list[dict], axes: dict, metrics: list[str]) -> list[str]:
    """The headline sentences: the best point by PCPG accuracy (mean over p), how often PCPG leads
    No Clustering, and the best clustering accuracy."""
    ps = [k.removeprefix("pcpg/accuracy/p") for k in metrics if k.startswith("pcpg/accuracy/p")]
    headline_lines = []
    scored = [
        (sum(_num(r, f"pcpg/accuracy/p{p}") or 0.0 for p in ps) / max(len(ps), 1), i)
        for i, r in enumerate(rows)
        if ps and all(_num(r, f"pcpg/accuracy/p{p}") is not None for p in ps)
    ]
    if scored:
        _, best = max(scored, key=lambda t: (t[0], -t[1]))  # the first of equals
        r = rows[best]
        where = ", ".join(f"{a}={plain(r.get(a))}" for a in axes)
        parts = []
        for p in ps:
            lead = _num(r, f"pcpg_lead/p{p}")
            parts.append(
                f"{_num(r, f'pcpg/accuracy/p{p}'):.3f} at p={p}"
                + (f" (lead over No Clustering {lead:+.3f})" if lead is not None else "")
            )
        headline_lines.append(
            f"Best point (highest PCPG accuracy, mean over p): {where}: PCPG "
            + "; ".join(parts)
            + "."
        )
    leads = [_num(r, f"pcpg_lead/p{p}") for r in rows for p in ps]
    leads = [v for v in leads if v is not None]
    if leads:
        headline_lines.append(
            f"PCPG is more accurate than No Clustering at {sum(v > 0 for v in leads)} of "
            f"{len(leads)} (point, p) pairs; its lead ranges from {min(leads):+.3f} to "
            f"{max(leads):+.3f}."
        )
    acc = [
        (_num(r, "clustering/accuracy"), i)
        for i, r in enumerate(rows)
        if _num(r, "clustering/accuracy") is not None
    ]
    if acc:
        v, i = max(acc, key=lambda t: (t[0], -t[1]))
        gap = _num(rows[i], "clustering/gap_to_ceiling")
        headline_lines.append(
            f"Best clustering accuracy {v:.3f} at "
            + ", ".join(f"{a}={plain(rows[i].get(a))}" for a in axes)
            + (
                f" (gap to the ceiling {gap:+.3f}: the ceiling minus clustering accuracy)"
                if gap is not None
                else ""
            )
            + "."
        )
    return headline_lines


def _sweep_figures(
    folder: Path, record: dict, keys: list[str], metrics: list[str], rows: list[dict]
) -> list[tuple[str, list[dict]]]:
    """The figures ``sweep.json`` names, inlined and captioned, grouped by axis in metric order."""
    import base64

    from pcpg_dist.common.errors import DataError
    from pcpg_dist.reporting.report_data import MAX_IMAGE_BYTES

    axes = record["axes"]
    safe = {re.sub(r"[^A-Za-z0-9._-]+", "_", k): k for k in keys}
    safe_axes = {re.sub(r"[^A-Za-z0-9._-]+", "_", a): a for a in axes}
    by_axis: dict[str, list[dict]] = {a: [] for a in axes}
    order = {k: i for i, k in enumerate(metrics)}
    for name in record["figures"]:
        path = folder / name
        if not inside(path, folder) or path.stat().st_size > MAX_IMAGE_BYTES:
            raise DataError(
                f"{folder}: figure {name} named in {SWEEP_JSON} is not a regular PNG file there "
                f"(at most {MAX_IMAGE_BYTES} bytes)"
            )
        stem = name.removesuffix(".png")
        metric_part, _, axis_part = stem.partition("__vs__")
        metric, axis = safe.get(metric_part, metric_part), safe_axes.get(axis_part, axis_part)
        others = [a for a in axes if a != axis]
        # as the figure drew them (sweep.draw_sweep): bars only where a point has a std over seeds
        bars = any((_num(r, metric + SWEEP_STD) or 0.0) > 0 for r in rows)
        caption = (
            f"{sweep_metric_label(metric)} against {axis}"
            + (f"; one line per value of {', '.join(others)}" if others else "")
            + (
                "; error bars: std over seeds, mean over environments."
                if bars
                else "; no error bars: no std over seeds."
            )
        )
        by_axis.setdefault(axis, []).append(
            {
                "title": f"{sweep_metric_label(metric)} vs {axis}",
                "caption": caption,
                "name": name,
                "uri": "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode(),
                "order": order.get(metric, len(order)),
            }
        )
    figures = [(a, sorted(f, key=lambda f: f["order"])) for a, f in by_axis.items() if f]
    return figures


def _sweep_provenance(run: dict | None, n_rows: int) -> tuple[str, list[tuple[str, str]]]:
    """The command that ran the sweep (without a point's suffix) and its provenance facts."""
    command = "—"
    provenance: list[tuple[str, str]] = []
    if run is not None:
        command = re.sub(r"\s*\[point [^\]]*\]$", "", str(run.get("command", "—")))
        prov = run.get("provenance", {})
        provenance = [
            ("git commit", str(prov.get("git_commit", "—"))),
            ("uv.lock sha256", str(prov.get("uv_lock", "—"))),
            ("base seed", str(run.get("config", {}).get("seed", "—"))),
            ("repetition seeds", plain(run.get("config", {}).get("seeds"))),
        ]
    provenance.append(("points", str(n_rows)))
    return command, provenance


def build_sweep(folder: Path, out_dir: Path) -> SweepPage:
    """The page model of a sweep folder (``sweep.json``, ``summary.csv``, the figures it names and
    each point's ``report/report.html`` and ``summary/run.json`` below ``points/``)."""
    from pcpg_dist.common.errors import DataError

    folder, out_dir = Path(folder), Path(out_dir)
    record = read_sweep_record(folder)
    axes = record["axes"]
    table = folder / "summary.csv"
    if not inside(table, folder):
        raise DataError(f"{folder}: no summary.csv (a regular file) beside {SWEEP_JSON}")
    rows = read_sweep_rows(table, axes)
    keys = [
        k
        for k in dict.fromkeys(k for r in rows for k in r)
        if k not in axes and k != "point" and not k.endswith(SWEEP_STD)
    ]
    metrics = _sweep_columns(keys)
    shown, run = _point_rows(folder, out_dir, rows, axes, metrics)
    headers = [
        *axes,
        *(
            sweep_metric_label(k) + (" ± std" if any(k + SWEEP_STD in r for r in rows) else "")
            for k in metrics
        ),
    ]
    headline_lines = _sweep_headline(rows, axes, metrics)
    figures = _sweep_figures(folder, record, keys, metrics, rows)
    command, provenance = _sweep_provenance(run, len(rows))
    return SweepPage(
        title=f"Sweep: {record['name']}",
        description=record["description"],
        headline=headline_lines,
        headers=headers,
        rows=shown,
        figures=figures,
        command=command,
        provenance=provenance,
        fixed=[
            (str(k), json.dumps(v) if isinstance(v, dict) else plain(v))
            for k, v in record["fixed"].items()
        ],
    )


def render_sweep(folder: Path, out_dir: Path) -> Path:
    """Write the sweep's ``report.html`` (self-contained; links to each point's own report are
    relative, so they work when the sweep folder is moved) into ``out_dir``."""
    page = build_sweep(folder, out_dir)
    html = jinja_environment().get_template("sweep.html.j2").render(s=page).encode()
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    path = Path(out_dir) / "report.html"
    atomic_write_bytes(path, html)
    return path


def write_sweep_files(out: Path, plan: SweepPlan, rows: list[dict[str, Any]]) -> list[Path]:
    """The sweep-level files of ``plan`` in ``out``: figures, ``summary.csv``, ``sweep.json`` and
    ``report.html`` (rendered from those files, as `pcpg report` renders it again), each written
    atomically; then every other PNG beside them (an earlier sweep's figure) is removed, so the
    folder describes exactly this sweep. Returns the files written."""
    out.mkdir(parents=True, exist_ok=True)
    figures = draw_sweep(out, plan.axes, rows)
    csv_path = _write_table(out, plan.axes, rows)
    record = {
        "format": SWEEP_FORMAT,
        "name": plan.base.name,
        "description": plan.description,
        "axes": plan.axes,
        "fixed": plan.fixed,
        "points": len(rows),
        "figures": [f.name for f in figures],
    }
    meta = out / SWEEP_JSON
    atomic_write_bytes(meta, json.dumps(record, indent=1, default=str).encode())
    report = render_sweep_report(out, out)
    keep = {f.name for f in figures}
    for stale in out.glob("*.png"):
        if stale.name not in keep and (stale.is_file() or stale.is_symlink()):
            stale.unlink(missing_ok=True)
    return [csv_path, meta, report, *figures]


def _write_table(out: Path, axes: dict[str, list], rows: list[dict[str, Any]]) -> Path:
    import pandas as pd

    metric_cols = sorted(
        {k for r in rows for k in r if k not in axes and k != "point"},
        key=lambda k: (k.removesuffix(STD), k.endswith(STD)),
    )
    table = pd.DataFrame(rows, columns=[*axes, *metric_cols, "point"])
    path = out / "summary.csv"
    atomic_write_bytes(path, table.to_csv(index=False, float_format="%.6g").encode())
    return path


def render_sweep_report(folder: Path, out_dir: Path) -> Path:
    """``report.html`` of the sweep in ``folder`` (its ``sweep.json``, ``summary.csv`` and figures),
    written to ``out_dir``: :func:`pcpg_dist.reporting.report.render_sweep`, styled like a run's report."""
    return render_sweep(Path(folder), Path(out_dir))
