"""Executors: what runs a stage's jobs. The runner hands every stage's jobs to one executor:
:class:`RayExecutor` fans them out as Ray tasks (a private Ray on a laptop, or a cluster),
:class:`LocalExecutor` runs them one after another in this process (a notebook, a test, a tuning
trial inside its own Ray task). Both give the same numbers: a job is a pure function of its
arguments, seeded from its own key."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np


class Executor(Protocol):
    """Runs jobs; ``put`` makes a value shareable by every job (Ray's object store, or itself)."""

    def put(self, value: Any) -> Any: ...

    def check(self, num_cpus: int, memory_bytes: float = 0.0) -> None:
        """Refuse, in one line, a request no worker can serve (before any job starts)."""

    def most_gpus(self) -> float:
        """The most GPUs one worker has (what a GPU setting is checked against)."""

    def slots(self, num_cpus: int) -> int:
        """How many jobs of ``num_cpus`` CPUs run at once (how finely to cut a stage's work)."""

    def widest(self) -> int:
        """The most CPUs one job can be given (the smallest worker's CPUs: a job fits anywhere)."""

    def fan_out(
        self,
        fn: Callable[..., Any],
        calls: Sequence[tuple],
        description: str,
        show_progress: bool = True,
    ) -> list[Any]:
        """What a domain's data generation is given (:class:`pcpg_dist.domains.base.FanOut`)."""

    def map(
        self,
        fn: Callable[..., Any],
        calls: Sequence[tuple],
        description: str,
        *,
        num_cpus: int,
        on_result: Callable[[int, Any], None],
        show_progress: bool,
        num_gpus: Sequence[float],
        here: bool = False,
    ) -> None:
        """``fn(*call)`` for every call, ``on_result(i, result)`` as each ends; ``here``: on
        the driver's machine (work on files only it has)."""


class LocalExecutor:
    """Every job in this process, in order, with one progress bar per stage."""

    def put(self, value: Any) -> Any:
        return value

    def check(self, num_cpus: int, memory_bytes: float = 0.0) -> None:
        pass  # this process runs every job, whatever it asks for

    def most_gpus(self) -> float:
        return float("inf")  # nothing to reserve: a job uses the device its config names

    def slots(self, num_cpus: int) -> int:
        return 1  # one job at a time

    def widest(self) -> int:
        return 1  # this process's thread count stays the config's

    def fan_out(self, fn, calls, description, show_progress=True) -> list[Any]:
        from pcpg_dist.domains.defaults import in_process

        return in_process(fn, calls, description, show_progress)

    def map(
        self, fn, calls, description, *, num_cpus, on_result, show_progress, num_gpus, here=False
    ) -> None:
        from pcpg_dist.common.progress import progress_bar

        if not calls:
            return
        with progress_bar(description, total=len(calls), enabled=show_progress) as advance:
            for i, call in enumerate(calls):
                on_result(i, fn(*call))
                advance(1)


class RayExecutor:
    """Every job as a Ray task, as many in flight as the cluster's CPUs and object store allow;
    results are handed over (and persisted by the caller) as each task finishes."""

    def put(self, value: Any) -> Any:
        import ray

        return ray.put(value)

    def check(self, num_cpus: int, memory_bytes: float = 0.0) -> None:
        from pcpg_dist.orchestration.ray_pool import check_resources

        check_resources(num_cpus, memory_bytes)

    def most_gpus(self) -> float:
        from pcpg_dist.orchestration.nodes import node_gpus

        return node_gpus()

    def slots(self, num_cpus: int) -> int:
        import ray

        return max(1, int(ray.cluster_resources().get("CPU", 1)) // max(1, num_cpus))

    def widest(self) -> int:
        from pcpg_dist.orchestration.nodes import node_capacities

        return max(1, int(min((n["CPU"] for n in node_capacities() if n["CPU"] >= 1), default=1)))

    def fan_out(self, fn, calls, description, show_progress=True) -> list[Any]:
        from pcpg_dist.orchestration.ray_pool import fan_out

        return fan_out(fn, calls, description, show_progress)

    def map(
        self, fn, calls, description, *, num_cpus, on_result, show_progress, num_gpus, here=False
    ) -> None:
        from pcpg_dist.orchestration.nodes import on_driver_node
        from pcpg_dist.orchestration.ray_pool import run_tasks

        limit = in_flight(num_cpus, max((nbytes(c) for c in calls), default=0)) if calls else 1
        run_tasks(
            fn,
            calls,
            description,
            num_cpus=num_cpus,
            on_result=on_result,
            show_progress=show_progress and bool(calls),
            max_in_flight=limit,
            num_gpus=list(num_gpus),
            options=on_driver_node() if here else None,
        )


def in_flight(num_cpus: int, arg_bytes: float) -> int:
    """How many tasks to submit at once: enough to keep every CPU busy, few enough that their
    queued arguments fit in half the object store."""
    import ray

    res = ray.cluster_resources()
    slots = max(1, int(res.get("CPU", 1) // max(num_cpus, 1)))
    store = res.get("object_store_memory", 2e8)
    return max(slots, min(4 * slots, int(0.5 * store / max(arg_bytes, 1.0))))


def nbytes(x: Any, depth: int = 0) -> int:
    """Rough size of a task argument: its NumPy arrays (a few levels into lists and objects)."""
    if isinstance(x, np.ndarray):
        return x.nbytes
    if depth > 4:
        return 64
    if isinstance(x, list | tuple):
        return sum(nbytes(v, depth + 1) for v in x)
    if isinstance(x, dict):
        return sum(nbytes(v, depth + 1) for v in x.values())
    if hasattr(x, "__dict__"):
        return sum(nbytes(v, depth + 1) for v in vars(x).values())
    return 64
