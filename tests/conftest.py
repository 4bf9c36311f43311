"""Shared fixtures: a seeded rng, one Ray instance for the whole session, a temporary MLflow store."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("RAY_ENABLE_UV_RUN_RUNTIME_ENV", "0")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")
os.environ.setdefault("MLFLOW_ENABLE_ASYNC_LOGGING", "false")


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
