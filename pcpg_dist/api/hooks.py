"""The hooks `pcpg run` and `pcpg sweep` hang on the runner: every point's local outputs
(:mod:`pcpg_dist.api.finish`), then its MLflow runs. Every local result is written before any
MLflow call, so a tracking server that goes down costs no local result."""

from __future__ import annotations

import time

from pcpg_dist.api.finish import finish_point
from pcpg_dist.common.progress import progress_bar
from pcpg_dist.orchestration.points import Outcome, Point, RunResult


class OutputsAndTracking:
    """Summary, agents and report for every point; with ``track``, an MLflow parent run per
    point (under ``sweep_parent_id`` in a sweep) started once the data is read, its child runs
    and the parent's results logged once every point's local outputs exist."""

    def __init__(
        self,
        tracking_uri: str | None = None,
        track: bool = True,
        show_progress: bool = True,
        sweep_parent_id: str | None = None,
    ) -> None:
        self.tracking_uri = tracking_uri
        self.track = track
        self.show_progress = show_progress
        self.sweep_parent_id = sweep_parent_id

    def started(self, points: list[Point]) -> None:
        if not self.track:
            return
        from pcpg_dist.tracking import Tracker

        for p in points:
            extra = (
                {"parent_run_id": self.sweep_parent_id, "params": p.params}
                if self.sweep_parent_id
                else {}
            )
            p.tracker = Tracker.start(
                p.cfg, self.tracking_uri, p.out, ikey=p.ikey, units=list(p.units.values()), **extra
            )

    def finished(self, outcomes: list[Outcome]) -> list[RunResult]:
        results = [finish_point(o) for o in outcomes]
        unlogged = {
            id(o): [e for e in o.point.units if not o.point.tracker.env_logged(e, o.point.ekeys[e])]
            if o.point.tracker is not None
            else []
            for o in outcomes
        }
        total = sum(len(v) for v in unlogged.values())
        enabled = self.show_progress and bool(total)
        with progress_bar("MLflow child runs", total=total, enabled=enabled) as advance:
            for o, result in zip(outcomes, results, strict=True):
                _log_point(o, result, unlogged[id(o)], advance)
        return results

    def failed(self, points: list[Point]) -> None:
        for p in points:
            if p.tracker is not None:
                p.tracker.fail()


def _log_point(outcome: Outcome, result: RunResult, unlogged: list[str], advance) -> None:
    """One point's MLflow runs, after every local result is written: child runs for the
    ``unlogged`` environments (``advance()`` after each), then the parent. A rerun logs only the
    environments without a FINISHED child run, recomputing nothing."""
    p = outcome.point
    if p.tracker is None:
        return
    from pcpg_dist.tracking import log_environment

    t0 = time.perf_counter()
    for e in unlogged:
        models = outcome.trained_cells(e)
        log_environment(
            p.tracker.child_info(e, p.ekeys[e], outcome.cluster_result(e)["metrics"]),
            e,
            str(outcome.eval_dir(e)),
            outcome.eval_metrics(e),
            [str(m.with_suffix(".pt")) for m in models],
        )
        advance()
    p.tracker.finish(result, agents_dir=p.out / "agents", report_dir=p.out / "report")
    result.stage_seconds["tracking"] = time.perf_counter() - t0
