"""The hooks `pcpg run` and `pcpg sweep` hang on the runner: every point's local outputs
(:mod:`pcpg_dist.api.finish`), then its MLflow runs. Every local result is written before any
MLflow call, so a tracking server that goes down costs no local result."""

from __future__ import annotations

import time

from pcpg_dist.api.finish import finish_point, place_report, render_report
from pcpg_dist.orchestration.executors import Executor, LocalExecutor
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
        executor = outcomes[0].executor or LocalExecutor()
        results = [finish_point(o) for o in outcomes]
        t0 = time.perf_counter()
        what = "Report" if len(results) == 1 else f"Reports of {len(results)} points"
        _here(
            executor, render_report, [(str(r.out_dir),) for r in results], what, self.show_progress
        )
        for r in results:
            place_report(r)
            r.stage_seconds["report"] = time.perf_counter() - t0
        tracked = [(o, r) for o, r in zip(outcomes, results, strict=True) if o.point.tracker]
        if not tracked:
            return results
        t0 = time.perf_counter()
        _log_runs(tracked, executor, self.show_progress)
        for _, result in tracked:
            result.stage_seconds["tracking"] = time.perf_counter() - t0
        return results

    def failed(self, points: list[Point]) -> None:
        for p in points:
            if p.tracker is not None:
                p.tracker.fail()


def _child_jobs(outcome: Outcome) -> list[tuple]:
    """The arguments of :func:`~pcpg_dist.tracking.log_environment` for each of the point's
    environments without a FINISHED child run of its unit (one search for all of them): a rerun
    logs only those, recomputing nothing."""
    p = outcome.point
    logged = p.tracker.logged_units()
    return [
        (
            p.tracker.child_info(e, p.ekeys[e], outcome.cluster_result(e)["metrics"]),
            e,
            str(outcome.eval_dir(e)),
            outcome.eval_metrics(e),
            [str(m.with_suffix(".pt")) for m in outcome.trained_cells(e)],
        )
        for e in p.units
        if (e, p.ekeys[e]) not in logged
    ]


def _log_runs(
    tracked: list[tuple[Outcome, RunResult]], executor: Executor, show_progress: bool
) -> None:
    """Every point's MLflow runs, logged by tasks on the driver's machine (where the run's files
    are) while the driver only waits: the environments' child runs, a share of them per task,
    then each point's parent run (its results, summary, report and agents model). After every
    local result is written, so a tracking server that goes down costs no local result."""
    from pcpg_dist.tracking import Tracker, log_environments

    jobs = [job for o, _ in tracked for job in _child_jobs(o)]
    shares = min(len(jobs), 2 * executor.slots(1))
    calls = [(jobs[i::shares],) for i in range(shares)]
    _here(executor, log_environments, calls, f"MLflow: {len(jobs)} environments", show_progress)
    parents = [
        (o.point.tracker, result, o.point.out / "agents", o.point.out / "report")
        for o, result in tracked
    ]
    what = "the parent run" if len(parents) == 1 else f"{len(parents)} parent runs"
    _here(executor, Tracker.finish, parents, f"MLflow: {what}", show_progress)


def _here(executor: Executor, fn, calls: list[tuple], description: str, show: bool) -> None:
    """``fn(*call)`` for every call, as tasks on the driver's machine; results dropped."""
    executor.map(
        fn,
        calls,
        description,
        num_cpus=1,
        on_result=lambda i, _: None,
        show_progress=show,
        num_gpus=[0.0] * len(calls),
        here=True,
    )
