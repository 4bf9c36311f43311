"""Shared fixtures: a seeded rng, one Ray instance for the whole session, a temporary MLflow store."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("RAY_ENABLE_UV_RUN_RUNTIME_ENV", "0")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")
os.environ.setdefault("MLFLOW_ENABLE_ASYNC_LOGGING", "false")
# The suite's two xdist workers share two cores, and each gives some tasks two CPUs (two torch
# threads): torch's OpenMP threads spinning at the end of each parallel region on a core the other
# worker holds took the stored-reference run from 40 s to 600 s. Sleeping at once changes no value
# (docs/scale.md, "Threads on a shared machine"); the tests' subprocesses and Ray workers inherit it.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def ray_session():
    """One in-process Ray with 2 CPUs, shared by every test that needs it, shut down at the end."""
    import ray

    from pcpg_dist.common.devices import set_threads

    set_threads(1)
    if not ray.is_initialized():
        # the product's own start: a private instance on 127.0.0.1 (never a `ray start` cluster
        # left on the machine), retried if a busy machine makes the node miss Ray's 30 s window
        from pcpg_dist.orchestration.ray_pool import init_ray

        init_ray(num_cpus=2)
    yield ray
    ray.shutdown()


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread():
    from pcpg_dist.common.devices import set_threads

    set_threads(1)


# Modules that run for minutes (real clusters, servers and `pcpg run` processes; measured
# 80-260 s each on a 2-core machine). Under xdist (`--dist loadfile`, one module per worker at a
# time) they start first, so the many short modules fill the other worker around them instead of
# two of these ending the run side by side. Only the order depends on this list, never a result.
LONG_MODULES = (
    "test_faults.py",
    "ops/test_ray_cluster.py",
    "orchestration/test_streaming.py",
    "ops/test_team_mode.py",
    "orchestration/test_sweep.py",
    "e2e/test_wheel.py",
)


def pytest_xdist_auto_num_workers(config) -> int:
    """``-n auto``: one worker per CPU this process may use, at most 4 (each worker holds its own
    torch, and the multi-process tests start Ray clusters of their own)."""
    from pcpg_dist.common.devices import available_cpus

    return min(available_cpus(), 4)


def pytest_collection_modifyitems(config, items) -> None:
    """The long modules first (in LONG_MODULES' order), then every other module with a slow test,
    then the rest; tests keep their order within a module."""

    def rank(item) -> tuple[int, int]:
        path = item.path.as_posix()
        for i, name in enumerate(LONG_MODULES):
            if path.endswith("/tests/" + name):
                return (0, i)
        return (1, 0) if item.get_closest_marker("slow") else (2, 0)

    modules: dict = {}
    for item in items:
        modules.setdefault(item.path, []).append(item)
    order = sorted(modules.values(), key=lambda its: min(rank(it) for it in its))
    items[:] = [it for its in order for it in its]
