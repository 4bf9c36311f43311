"""Starting or joining Ray, and running a batch of remote tasks with a progress bar.

Embedded default: Ray in-process on this machine's CPUs. With ``--ray-address`` or
``RAY_ADDRESS`` the same code joins an existing cluster (``ray start --head``).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Sequence
from typing import Any

from pcpg_dist.errors import PcpgError, ServiceError
from pcpg_dist.parallel import available_cpus


def init_ray(address: str | None = None, num_cpus: int | None = None) -> None:
    """Join ``address`` (or ``RAY_ADDRESS``) if given, else start Ray in-process; idempotent."""
    import ray

    if ray.is_initialized():
        return
    address = address or os.environ.get("RAY_ADDRESS") or None
    runtime_env = {"env_vars": {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                                "TOKENIZERS_PARALLELISM": "false"}}
    if not address:
        # Ray's `uv run` hook would start every local worker through `uv run` and ship the working
        # directory (~20 s here); in-process workers already share this interpreter. The flag is
        # read from ray_constants at init time, so set it there too if ray was imported already.
        os.environ.setdefault("RAY_ENABLE_UV_RUN_RUNTIME_ENV", "0")
        from ray._private import ray_constants

        ray_constants.RAY_ENABLE_UV_RUN_RUNTIME_ENV = os.environ["RAY_ENABLE_UV_RUN_RUNTIME_ENV"] not in ("0", "false", "False")
    try:
        if address:
            ray.init(address=address, log_to_driver=False, runtime_env=runtime_env)
        else:
            ray.init(num_cpus=num_cpus or available_cpus(), include_dashboard=False,
                     object_store_memory=300_000_000, log_to_driver=False, runtime_env=runtime_env,
                     logging_level=logging.WARNING)
    except (ConnectionError, RuntimeError, ValueError) as e:
        raise ServiceError(f"cannot start or join Ray at {address or 'local'}: {e}") from None


def run_tasks(fn: Callable[..., Any], calls: Sequence[tuple], description: str,
              num_cpus: int = 1, max_retries: int = 3, on_result: Callable[[int, Any], None] | None = None,
              show_progress: bool = True) -> list[Any]:
    """Run ``fn(*args)`` for every ``args`` in ``calls`` as Ray tasks; results in call order.

    ``max_retries`` re-runs a task whose worker process died (results are deterministic in the
    arguments, so a retry gives the same numbers). ``on_result(i, result)`` fires as each finishes,
    so callers can persist finished work before the rest is done.
    """
    import ray

    from pcpg_dist.progress import progress_bar

    remote = ray.remote(num_cpus=num_cpus, max_retries=max_retries)(fn)
    refs = [remote.remote(*args) for args in calls]
    index = {ref: i for i, ref in enumerate(refs)}
    results: list[Any] = [None] * len(refs)
    pending = list(refs)
    with progress_bar(description, total=len(refs), enabled=show_progress) as advance:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                i = index[ref]
                try:
                    results[i] = ray.get(ref)
                except ray.exceptions.RayTaskError as e:
                    # A user mistake inside a task surfaces as the project's own one-line error.
                    if isinstance(e.cause, PcpgError):
                        raise e.cause from None
                    raise
                if on_result is not None:
                    on_result(i, results[i])
                advance()
    return results
