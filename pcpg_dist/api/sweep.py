"""`pcpg sweep`: every point of a sweep through the runner together, then the sweep's table,
figures and page, and its MLflow run above the points' (:mod:`pcpg_dist.orchestration.sweep`
plans the points; :mod:`pcpg_dist.reporting.sweep_page` writes the outputs)."""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pcpg_dist.api.hooks import OutputsAndTracking
from pcpg_dist.common.point_labels import axis_text
from pcpg_dist.orchestration.runner import run_points
from pcpg_dist.orchestration.sweep import SweepPlan, best_points, describe, plan_sweep
from pcpg_dist.pipeline.declared import STAGES

STAGE_NOTE = (
    "Stage times (`time/<stage>_seconds`, `time/sweep_seconds`) are logged here only: the points' stages "
    "run batched together (shared data and clusterings), so no point has a time of its own; they are "
    "those of the last call that computed points."
)


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


def run_sweep(
    config: str | Path | dict,
    axes_args: list[str],
    overrides: list[str] | None = None,
    workdir: Path = Path("runs"),
    tracking_uri: str | None = None,
    track: bool = True,
    show_progress: bool = True,
    command: str = "",
) -> SweepResult:
    """Run (or resume) a sweep over ``axes_args`` (``KEY=v1,v2``) and the file's ``sweep:`` section."""
    from pcpg_dist.reporting.sweep_page import write_sweep_files

    t0 = time.perf_counter()
    plan = plan_sweep(config, axes_args, overrides, workdir, command)
    tracker = _start_tracker(plan, tracking_uri) if track else None
    try:
        done = {id(p): _finished(p.out, p.cfg, track, tracking_uri) for p in plan.points}
        todo = [p for p in plan.points if done[id(p)] is None]
        hooks = OutputsAndTracking(
            tracking_uri, track, show_progress, tracker.parent_id if tracker else None
        )
        results = (
            run_points(todo, plan.root / "cache", hooks=hooks, show_progress=show_progress)
            if todo
            else []
        )
        if tracker is not None:  # reused points are this sweep's too (one child per point)
            for p in plan.points:
                if done[id(p)] is not None:
                    tracker.add_reused(done[id(p)][1])
        metrics_of = {id(p): r.metrics for p, r in zip(todo, results, strict=True)}
        rows = _rows(plan, {id(p): metrics_of.get(id(p)) or done[id(p)][0] for p in plan.points})
        files = write_sweep_files(plan.out, plan, rows)
        if tracker is not None:
            _finish_tracker(tracker, plan, rows, files, results, t0)
    except BaseException:
        if tracker is not None:
            tracker.fail()
        raise
    return SweepResult(
        plan.out,
        plan.axes,
        rows,
        [f for f in files if f.suffix == ".png"],
        time.perf_counter() - t0,
        ran=len(todo),
        computed=results[0].computed if results else {},
        parent_run_id=tracker.parent_id if tracker else None,
    )


def _rows(plan: SweepPlan, metrics: dict[int, dict]) -> list[dict[str, Any]]:
    """One row per point: its axis values, its folder and its headline metrics."""
    from pcpg_dist.reporting.sweep_files import headline

    return [
        {
            **{k: axis_text(v) if isinstance(v, list | dict) else v for k, v in combo.items()},
            "point": p.out.name,
            **headline(metrics[id(p)]),
        }
        for p, combo in zip(plan.points, plan.combos, strict=True)
    ]


def _start_tracker(plan: SweepPlan, tracking_uri: str | None):
    from pcpg_dist.tracking.trackers import SweepTracker

    sweep_key = hashlib.sha256(
        json.dumps(
            [plan.base.hash(), [[describe(c)] for c in plan.combos]], sort_keys=True
        ).encode()
    ).hexdigest()[:16]
    return SweepTracker.start(plan.base.name, sweep_key, plan.axes, plan.description, tracking_uri)


def _finish_tracker(tracker, plan: SweepPlan, rows, files, results, t0: float) -> None:
    """The sweep run's headline, its best points, its files and the batched stage times."""
    from pcpg_dist.reporting.sweep_figures import _readable

    best, where = best_points(plan.axes, rows)
    lines = [
        "Best points: "
        + "; ".join(f"{_readable(k)} {best[f'best/{k}']:.3f} at `{w}`" for k, w in where.items())
        if where
        else "",
        STAGE_NOTE,
    ]
    note = plan.description + "".join(f"\n\n{line}" for line in lines)
    timings = {}
    if results:  # the stages this call computed, all its points batched: the sweep's, not a point's
        timings = {
            f"time/{s}_seconds": results[0].stage_seconds[s]
            for s in STAGES
            if s in results[0].stage_seconds and s not in results[0].cached_stages
        }
        timings["time/sweep_seconds"] = time.perf_counter() - t0
    tracker.finish(
        best, files, best_points=where, timings=timings, note=note, inputs=_data_inputs(plan)
    )


def _data_inputs(plan: SweepPlan) -> list:
    """Every point's data (points sharing data share it), for the sweep run's dataset inputs."""
    from pcpg_dist.pipeline.declared import input_key
    from pcpg_dist.tracking.datasets import data_inputs

    found = {}
    for p in plan.points:
        for i in data_inputs(p.cfg, p.ikey or input_key(p.cfg)):
            found.setdefault((i.name, i.digest), i)
    return list(found.values())


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
