"""What the runner calls around the stages, so that tracking, reports and exports hang on it
without the runner importing any of them (imitation injects its logger the same way).

The api layer (:mod:`pcpg_dist.api.hooks`) gives `pcpg run` and `pcpg sweep` the hooks that write
the summary, the agents and the report, and log to MLflow; without hooks the runner returns each
point's :class:`~pcpg_dist.orchestration.points.Outcome` (what its stages left in the cache)."""

from __future__ import annotations

from typing import Any, Protocol

from pcpg_dist.orchestration.points import Outcome, Point


class RunHooks(Protocol):
    def started(self, points: list[Point]) -> None:
        """The data is read and checked; the stages that do the work are about to run."""

    def finished(self, outcomes: list[Outcome]) -> list[Any]:
        """Every stage is done for every point; returns what the run returns, one per point."""

    def failed(self, points: list[Point]) -> None:
        """A stage failed (or the run was interrupted); the error is raised after this."""


class NoHooks:
    """Nothing around the stages: the run returns each point's outcome."""

    def started(self, points: list[Point]) -> None:
        pass

    def finished(self, outcomes: list[Outcome]) -> list[Any]:
        return outcomes

    def failed(self, points: list[Point]) -> None:
        pass
