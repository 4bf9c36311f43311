"""A point's local outputs once its stages are done: the summary tables and figures, the agents
folder and the report, built aside and swapped in by renames (local only; MLflow comes after,
:mod:`pcpg_dist.api.hooks`). The report is rendered by a task on the driver's machine
(:func:`render_report`, between :func:`finish_point` and :func:`place_report`), so a sweep's
reports render side by side and the driver does no per-environment reading for them."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

from pcpg_dist.common.files import atomic_write_bytes
from pcpg_dist.common.run_folders import write_agents_index
from pcpg_dist.orchestration.points import Outcome, RunResult
from pcpg_dist.pipeline.declared import CODE_VERSION, PIPELINE

STAGING = ".finishing"  # RUN/.finishing: the next summary, agents and report while they are written


def _collect_agents(target: Path, models: dict[str, list[Path]]) -> Path:
    """``target/<env>/<group>.pt|.json`` (a new folder): every trained cell of the run, for the pyfunc
    model, and ``target/index.json``, the hash of each file per environment."""
    for env, paths in models.items():
        (target / env).mkdir(parents=True)
        for i, p in enumerate(paths):
            for suffix in (".pt", ".json"):
                shutil.copyfile(p.with_suffix(suffix), target / env / f"group{i:03d}{suffix}")
    write_agents_index(target)
    return target


def _swap_in(out: Path, staging: Path, names: tuple[str, ...]) -> None:
    """Replace ``out/<name>`` by ``staging/<name>`` for each name, by renames. The old summary is
    moved aside first, so between the renames there is no summary rather than a mixed one."""
    old = staging / "old"
    old.mkdir(exist_ok=True)
    if "summary" in names and (out / "summary").exists():
        (out / "summary").rename(old / "summary")
    for name in names:
        if (out / name).exists():
            (out / name).rename(old / name)
        (staging / name).rename(out / name)


def _cached_stages(outcome: Outcome, out: Path, times: dict[str, float]) -> list[str]:
    """The stages served wholly from the cache; each keeps the timing of the run that computed it."""
    cached = [s.name for s in PIPELINE if not outcome.computed[s.counter]]
    try:
        before = json.loads((out / "summary" / "run.json").read_text()).get("stage_seconds", {})
    except (OSError, ValueError, AttributeError):
        before = {}
    for s in cached:
        if isinstance(before.get(s), int | float):
            times[s] = before[s]
    return cached


def finish_point(outcome: Outcome) -> RunResult:
    """Across one point's environments: summary tables, figures and agents (local only); the
    report is left to :func:`render_report` and :func:`place_report`. The times and counts are
    the batch's (a sweep's points ran their stages together)."""
    from pcpg_dist.common.provenance import provenance
    from pcpg_dist.reporting.summary import write_summary

    p, times = outcome.point, dict(outcome.times)
    t0 = time.perf_counter()
    cfg, out, envs = p.cfg, p.out, list(p.units)
    # Summary, agents and report are built in `staging` and swapped in by renames, the summary
    # (run.json inside) last: a killed write leaves the old complete summary or none, never a mix.
    staging = out / STAGING
    if staging.exists():  # left by a run killed while finishing
        shutil.rmtree(staging)
    staging.mkdir(parents=True)
    per_env = {e: outcome.eval_metrics(e) for e in envs}
    cluster_metrics = {e: outcome.cluster_result(e)["metrics"] for e in envs}
    eval_dirs = {e: outcome.eval_dir(e) for e in envs}
    metrics = write_summary(cfg, staging / "summary", eval_dirs, per_env, cluster_metrics)
    _collect_agents(staging / "agents", {e: outcome.trained_cells(e) for e in envs})
    times["summary"] = time.perf_counter() - t0
    cached = _cached_stages(outcome, out, times)
    result = RunResult(
        out_dir=out,
        metrics=metrics,
        clustering=cluster_metrics,
        stage_seconds=times,
        computed=outcome.computed,
        cached_stages=cached,
        parent_run_id=p.tracker.parent_id if p.tracker else None,
    )
    run_info = {
        "config": cfg.model_dump(mode="json"),
        "config_hash": cfg.hash(),
        "command": p.command or f"pcpg run <config of {cfg.name}>",
        "overrides": p.params,
        "provenance": provenance(),
        "stage_seconds": times,
        "cached_stages": cached,
        "parent_run_id": result.parent_run_id,
        "computed": outcome.computed,
        "code_version": CODE_VERSION,
        "input_key": p.ikey,
        "batch_points": outcome.batch,
    }
    atomic_write_bytes(
        staging / "summary" / "run.json", json.dumps(run_info, indent=1, default=str).encode()
    )
    _swap_in(out, staging, ("agents", "summary"))
    return result


def render_report(out: str) -> None:
    """The report of the run in ``out`` (its new summary) into ``out``'s staging folder: a task's
    body, run where the run's files are."""
    from pcpg_dist.reporting.report import render

    render(Path(out) / "summary", Path(out) / STAGING / "report")


def place_report(result: RunResult) -> None:
    """Swap the report :func:`render_report` wrote in and drop the staging folder."""
    out = result.out_dir
    _swap_in(out, out / STAGING, ("report",))
    shutil.rmtree(out / STAGING)
    result.report = out / "report" / "report.html"
