"""`pcpg sweep`: a grid over config axes, every point run together on Ray, shared units run once.

The points of a sweep are configs that differ in a few dotted keys. They run as one batch through
:func:`pcpg_dist.orchestration.runner.run_points`: their tasks interleave on the cluster, and the content-keyed
cache (``<workdir>/<name>/cache``, the same one `pcpg run` of the base config uses) shares every
unit whose inputs are equal: points that differ only in ``bc.*`` train on one dataset and one
clustering; points that differ only in evaluation settings reuse the trained agents.

Outputs under ``<workdir>/<name>/sweep/``: ``points/<point>/`` (each point's summary, report and
agents, as `pcpg run` writes them), ``summary.csv`` (one row per point: its axes, the headline
metrics and their std over seeds), one PNG per headline metric against each axis, ``sweep.json``
(the axes, the fixed overrides, the figures) and ``report.html``. MLflow: one parent run per
sweep, one child per point (its overrides as params, its headline metrics), the environments under
each point as in `pcpg run`.

A point's folder is named by its axis values and a hash of everything that makes its config
differ from the file (axes, fixed overrides, the validated config's hash), so two sweeps of one
config never share a point folder and every sweep finds its own finished points again. ``points/``
keeps the points of every sweep run there; the files beside it describe the last sweep only (a
figure the last sweep did not draw is removed).

Rerunning the same command is idempotent: finished points are read back, not rerun or relogged;
adding a value to an axis runs only the new points.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import re
import reprlib
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pcpg_dist.common.errors import ConfigError, DataError
from pcpg_dist.common.files import atomic_write_bytes
from pcpg_dist.config.overrides import apply_overrides, parse_overrides, read_raw, sweep_points

STD = "/std"
SWEEP_JSON = (
    "sweep.json"  # the sweep-level record beside summary.csv: axes, fixed overrides, figures
)
SWEEP_FORMAT = 1


@dataclass
class SweepResult:
    out_dir: Path
    axes: dict[str, list]
    rows: list[dict[str, Any]]
    figures: list[Path]
    seconds: float
    ran: int  # points computed or logged by this call (the rest were finished before)
    computed: dict[str, int] = field(default_factory=dict)
    parent_run_id: str | None = None


def ps_of(keys) -> list[str]:
    """The p values of ``pcpg/accuracy/p…`` among ``keys``, as written, largest first."""
    return sorted(
        {k.rsplit("/p", 1)[1] for k in keys if re.fullmatch(r"pcpg/accuracy/p[0-9.]+", k)},
        key=float,
        reverse=True,
    )


def headline_keys(metrics: dict[str, float]) -> list[str]:
    """What a sweep compares: clustering quality, PCPG and No Clustering at every p and PCPG's lead."""
    keys = [
        k
        for k in (
            "clustering/accuracy",
            "clustering/ceiling",
            "clustering/gap_to_ceiling",
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


BATCHED_STAGES = ("generate", "cluster", "train", "evaluate")
STAGE_NOTE = (
    "Stage times (`time/<stage>_seconds`, `time/sweep_seconds`) are logged here only: the points' stages "
    "run batched together (shared data and clusterings), so no point has a time of its own; they are "
    "those of the last call that computed points."
)


def _p_keys(rows: list[dict[str, Any]]) -> list[str]:
    """The p values of the rows' ``pcpg/accuracy/p<x>`` keys, largest first (as written in the keys)."""
    found = {
        k.rsplit("/p", 1)[1]
        for r in rows
        for k in r
        if re.fullmatch(r"pcpg/accuracy/p[0-9.e-]+", k)
    }
    return sorted(found, key=float, reverse=True)


def best_points(
    axes: dict[str, list], rows: list[dict[str, Any]]
) -> tuple[dict[str, float], dict[str, str]]:
    """The sweep run's headline: ``best/<metric>`` for clustering accuracy, PCPG accuracy at the
    largest p and PCPG's lead at the smallest p, and for each the point that has it (its MLflow
    run name; ``(+n tied)`` when other points have the same value)."""
    from pcpg_dist.tracking.runs import point_label

    ps = _p_keys(rows)
    keys = [
        "clustering/accuracy",
        *([f"pcpg/accuracy/p{ps[0]}", f"pcpg_lead/p{ps[-1]}"] if ps else []),
    ]
    best, where = {}, {}
    for key in keys:
        have = [r for r in rows if isinstance(r.get(key), int | float) and math.isfinite(r[key])]
        if not have:
            continue
        top = max(r[key] for r in have)
        tied = [r for r in have if r[key] == top]
        best[f"best/{key}"] = float(top)
        where[key] = point_label({a: _fmt(tied[0][a]) for a in axes}) + (
            f" (+{len(tied) - 1} tied)" if len(tied) > 1 else ""
        )
    return best, where


def point_slug(
    axes: dict[str, Any], fixed: dict[str, Any] | None = None, config_hash: str = ""
) -> str:
    """A stable folder name for a point: its axis values, readable and made safe, plus a short hash
    of everything that sets its config apart (axes, fixed overrides, the config's own hash)."""
    from pcpg_dist.common.run_folders import slug

    text = "_".join(
        f"{k}={json.dumps(v) if isinstance(v, list | dict) else v}" for k, v in axes.items()
    )
    return slug(text, [axes, fixed or {}, config_hash], fallback="point")


def _fmt(v: Any) -> str:
    return json.dumps(v) if isinstance(v, list | dict | bool) or v is None else str(v)


def _finished(out: Path, cfg, track: bool, uri: str | None) -> tuple[dict, str] | None:
    """The point's metrics and MLflow run id if an earlier call finished it (same config, logged
    when tracking)."""
    try:
        run = json.loads((out / "summary" / "run.json").read_text())
        metrics = json.loads((out / "summary" / "metrics.json").read_text())
    except (OSError, ValueError):
        return None
    if (
        not isinstance(run, dict)
        or run.get("config_hash") != cfg.hash()
        or not isinstance(metrics, dict)
    ):
        return None
    if track and not _run_finished(uri, run.get("parent_run_id")):
        return None
    return metrics, run.get("parent_run_id")


def _run_finished(uri: str | None, run_id: Any) -> bool:
    """Whether the point's MLflow run exists and finished (a deleted or killed one is redone)."""
    if not isinstance(run_id, str) or not run_id:
        return False
    from mlflow import MlflowClient
    from mlflow.exceptions import MlflowException

    from pcpg_dist.tracking.store import default_tracking_uri

    try:
        info = MlflowClient(uri or default_tracking_uri()).get_run(run_id).info
    except MlflowException:
        return False
    return info.status == "FINISHED" and info.lifecycle_stage == "active"


@dataclass
class SweepPlan:
    """A sweep before it runs: its base config, axes, fixed overrides and points (folders included)."""

    base: Any  # ExperimentConfig of the file with the fixed overrides
    axes: dict[str, list]
    fixed: dict[str, Any]
    combos: list[dict[str, Any]]
    points: list  # runner.Point, one per combo
    root: Path  # <workdir>/<name>
    description: str

    @property
    def out(self) -> Path:
        return self.root / "sweep"


def plan_sweep(
    config: str | Path,
    axes_args: list[str],
    overrides: list[str] | None = None,
    workdir: Path = Path("runs"),
    command: str = "",
) -> SweepPlan:
    """Validate the sweep (every point's config) and name its points' folders; nothing runs."""
    from pcpg_dist.config.experiment import parse_config
    from pcpg_dist.orchestration.points import Point

    config = Path(config)
    raw, section = read_raw(config)
    fixed = parse_overrides(overrides or [])
    raw = apply_overrides(raw, fixed)
    base = parse_config(raw, source=str(config), base_dir=config.parent)
    axes, combos = sweep_points(section, axes_args, base.domain)
    if both := sorted(set(fixed) & set(axes)):  # the axis would silently win
        raise ConfigError(
            f"{both[0]!r} is both a sweep axis and a single value ({both[0]}={reprlib.repr(fixed[both[0]])}); "
            f"give it once"
        )
    root = Path(workdir).resolve() / base.name
    points = []
    for combo in combos:
        cfg = parse_config(
            apply_overrides(raw, combo),
            source=f"{config} with {_describe(combo)}",
            base_dir=config.parent,
        )
        points.append(
            Point(
                cfg,
                root / "sweep" / "points" / point_slug(combo, fixed, cfg.hash()),
                params={k: _fmt(v) for k, v in combo.items()},
                command=f"{command} [point {_describe(combo)}]" if command else "",
            )
        )
    description = (
        f"Sweep of {base.name} ({config.name}) over {', '.join(axes)}: {len(points)} points "
        f"({' x '.join(str(len(v)) for v in axes.values())})"
        + (f"; fixed: {_describe(fixed)}" if fixed else "")
    )
    return SweepPlan(base, axes, fixed, combos, points, root, description)


def run_sweep(
    config: str | Path,
    axes_args: list[str],
    overrides: list[str] | None = None,
    workdir: Path = Path("runs"),
    tracking_uri: str | None = None,
    track: bool = True,
    show_progress: bool = True,
    command: str = "",
) -> SweepResult:
    """Run (or resume) a sweep over ``axes_args`` (``KEY=v1,v2``) and the file's ``sweep:`` section."""
    from pcpg_dist.api.hooks import OutputsAndTracking
    from pcpg_dist.orchestration.runner import run_points

    t0 = time.perf_counter()
    plan = plan_sweep(config, axes_args, overrides, workdir, command)
    base, axes, combos, points, root, out = (
        plan.base,
        plan.axes,
        plan.combos,
        plan.points,
        plan.root,
        plan.out,
    )
    description = plan.description
    tracker = None
    if track:
        from pcpg_dist.tracking.trackers import SweepTracker

        sweep_key = hashlib.sha256(
            json.dumps([base.hash(), [[_describe(c)] for c in combos]], sort_keys=True).encode()
        ).hexdigest()[:16]
        tracker = SweepTracker.start(base.name, sweep_key, axes, description, tracking_uri)
    try:
        done = {id(p): _finished(p.out, p.cfg, track, tracking_uri) for p in points}
        todo = [p for p in points if done[id(p)] is None]
        results = (
            run_points(
                todo,
                root / "cache",
                hooks=OutputsAndTracking(
                    tracking_uri, track, show_progress, tracker.parent_id if tracker else None
                ),
                show_progress=show_progress,
            )
            if todo
            else []
        )
        if tracker is not None:  # reused points are this sweep's too (one child per point)
            for p in points:
                if done[id(p)] is not None:
                    tracker.add_reused(done[id(p)][1])
        metrics_of = {id(p): r.metrics for p, r in zip(todo, results, strict=True)}
        computed = results[0].computed if results else {}
        rows = []
        for p, combo in zip(points, combos, strict=True):
            m = metrics_of[id(p)] if done[id(p)] is None else done[id(p)][0]
            rows.append(
                {
                    **{k: _fmt(v) if isinstance(v, list | dict) else v for k, v in combo.items()},
                    "point": p.out.name,
                    **headline(m),
                }
            )
        files = write_sweep_files(out, plan, rows)
        figures = [f for f in files if f.suffix == ".png"]
        if tracker is not None:
            best, where = best_points(axes, rows)
            note = description + "".join(
                f"\n\n{line}"
                for line in [
                    "Best points: "
                    + "; ".join(
                        f"{_readable(k)} {best[f'best/{k}']:.3f} at `{w}`" for k, w in where.items()
                    )
                    if where
                    else "",
                    STAGE_NOTE,
                ]
            )
            timings = {}
            if (
                results
            ):  # the stages this call computed, all its points batched: the sweep's, not a point's
                timings = {
                    f"time/{s}_seconds": results[0].stage_seconds[s]
                    for s in BATCHED_STAGES
                    if s in results[0].stage_seconds and s not in results[0].cached_stages
                }
                timings["time/sweep_seconds"] = time.perf_counter() - t0
            tracker.finish(best, files, best_points=where, timings=timings, note=note)
    except BaseException:
        if tracker is not None:
            tracker.fail()
        raise
    return SweepResult(
        out,
        axes,
        rows,
        figures,
        time.perf_counter() - t0,
        ran=len(todo),
        computed=computed,
        parent_run_id=tracker.parent_id if tracker else None,
    )


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


def _describe(combo: dict[str, Any]) -> str:
    return ", ".join(f"{k}={_fmt(v)}" for k, v in combo.items())


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


def _numeric(values: list) -> bool:
    return all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)


# Readable names for the figures (the raw key stays in brackets on the axis).
AXIS_LABELS = {
    "pbtg.noise_max": "largest per-trajectory action noise",
    "pbtg.noise_min": "smallest action noise",
    "clustering.k": "k (clusters)",
    "clustering.method": "clustering method",
    "bc.epochs": "BC epochs",
    "bc.hidden_size": "BC hidden size",
    "bc.lr": "BC learning rate",
    "pbtg.trajectories_per_style": "trajectories per style",
    "pbtg.dataset_per_style": "dataset trajectories per style",
}
_METRIC_LABELS = {
    "clustering/accuracy": "clustering accuracy",
    "clustering/ceiling": "supervised ceiling",
    "clustering/gap_to_ceiling": "gap to the supervised ceiling",
    "cross/diagonal_mean": "cross-accuracy diagonal (mean)",
}
_PER_P = {
    "pcpg/accuracy/p": "PCPG accuracy",
    "baseline/accuracy/p": "No Clustering accuracy",
    "pcpg_lead/p": "PCPG lead over No Clustering",
}


def _readable(metric: str) -> str:
    """``pcpg/accuracy/p0.5`` -> "PCPG accuracy at p = 0.5"; a key without a name stays as it is."""
    for prefix, name in _PER_P.items():
        if metric.startswith(prefix):
            return f"{name} at p = {metric.removeprefix(prefix)}"
    return _METRIC_LABELS.get(metric, metric)


def _axis_label(axis: str) -> str:
    return f"{AXIS_LABELS[axis]} ({axis})" if axis in AXIS_LABELS else axis


def draw_sweep(out: Path, axes: dict[str, list], rows: list[dict[str, Any]]) -> list[Path]:
    """One PNG per headline metric against each axis: one line per value of the other axes, error
    bars the std over seeds (each environment's, averaged over environments: the ``/std`` keys),
    where the metric has one (clustering is fitted once per point and PCPG's lead is a difference
    of means: none); the title says which. Ticks only at the swept values (a numeric axis keeps its spacing). Lines
    are drawn side by side (a small horizontal offset, a marker each), so equal lines stay visible,
    and the legend names the ones that are identical."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pcpg_dist.tracking.runs import short_keys

    metrics = [
        k
        for k in dict.fromkeys(k for r in rows for k in r)
        if k not in axes and k != "point" and not k.endswith(STD)
    ]
    palette = [
        "#0072B2",
        "#E69F00",
        "#009E73",
        "#CC79A7",
        "#56B4E9",
        "#D55E00",
        "#F0E442",
        "#000000",
    ]
    markers = ["o", "s", "^", "D", "v", "P", "X", "*"]
    short = short_keys(list(axes))
    paths = []
    for axis, values in axes.items():
        others = [a for a in axes if a != axis]
        xs = [float(v) for v in values] if _numeric(values) else list(range(len(values)))
        gaps = [b - a for a, b in zip(sorted(xs), sorted(xs)[1:], strict=False) if b > a]
        width = min(gaps) if gaps else 1.0
        for metric in metrics:
            fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=110)
            groups: dict[tuple, list[dict]] = {}
            for r in rows:
                groups.setdefault(tuple(_fmt(r[o]) for o in others), []).append(r)
            lines: dict[tuple, list] = {}
            for key, members in groups.items():
                by_x = {_fmt(r[axis]): r for r in members}
                pts = [
                    (x, by_x[_fmt(v)]) for x, v in zip(xs, values, strict=True) if _fmt(v) in by_x
                ]
                lines[key] = [
                    (x, r.get(metric, math.nan), r.get(metric + STD, 0.0)) for x, r in pts
                ]
            same = {
                key: [other for other in lines if other != key and lines[other] == lines[key]]
                for key in lines
            }
            has_std = False
            n = len(lines)
            for gi, (key, pts) in enumerate(lines.items()):
                shift = (gi - (n - 1) / 2) * width * 0.04 if n > 1 else 0.0
                err = [
                    e if isinstance(e, int | float) and math.isfinite(e) else 0.0 for _, _, e in pts
                ]
                has_std |= any(e > 0 for e in err)
                label = (
                    ", ".join(f"{short[o]}={k}" for o, k in zip(others, key, strict=True)) or None
                )
                if label and same[key]:
                    label += (
                        " (same as "
                        + "; ".join(
                            ", ".join(f"{short[o]}={k}" for o, k in zip(others, twin, strict=True))
                            for twin in same[key]
                        )
                        + ")"
                    )
                ax.errorbar(
                    [x + shift for x, _, _ in pts],
                    [y for _, y, _ in pts],
                    yerr=err,
                    marker=markers[gi % len(markers)],
                    capsize=3,
                    label=label,
                    color=palette[gi % len(palette)],
                    alpha=0.9,
                )
            ax.set_xticks(xs, [_fmt(v) for v in values])
            ax.set_xlabel(_axis_label(axis))
            ax.set_ylabel(_readable(metric))
            ax.grid(alpha=0.3)
            if len(lines) > 1:
                ax.legend(fontsize=7, loc="best")
            bars = (
                "error bars: std over seeds, mean over environments"
                if has_std
                else "no error bars: no std over seeds"
            )
            ax.set_title(
                f"{_readable(metric)} vs {AXIS_LABELS.get(axis, axis)}\n({bars})", fontsize=10
            )
            fig.tight_layout()
            path = (
                out
                / f"{re.sub(r'[^A-Za-z0-9._-]+', '_', metric)}__vs__{re.sub(r'[^A-Za-z0-9._-]+', '_', axis)}.png"
            )
            png = io.BytesIO()
            fig.savefig(png, format="png")
            plt.close(fig)
            atomic_write_bytes(path, png.getvalue())
            paths.append(path)
    return paths


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


def _read_rows(path: Path, axes: dict[str, list]) -> list[dict[str, Any]]:
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


def render_sweep_report(folder: Path, out_dir: Path) -> Path:
    """``report.html`` of the sweep in ``folder`` (its ``sweep.json``, ``summary.csv`` and figures),
    written to ``out_dir``: :func:`pcpg_dist.reporting.report.render_sweep`, styled like a run's report."""
    from pcpg_dist.reporting.report import render_sweep

    return render_sweep(Path(folder), Path(out_dir))
