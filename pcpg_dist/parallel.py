"""Ray and thread-count helpers shared by the runner, the tests and the stages' Ray wrappers.

Stages never import Ray; the runner wraps them. Torch in a reused Ray worker keeps the thread count
of its first task, and oversubscribed torch on 2 cores was measured ~100x slower, so every task
calls :func:`set_threads` with the CPUs it was given before touching torch.
"""

from __future__ import annotations

import os


def set_threads(n: int) -> None:
    """Limit torch (and BLAS via env vars for subprocesses) to ``n`` threads in this process."""
    n = max(1, int(n))
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = str(n)
    # numba: the runtime setting, never NUMBA_NUM_THREADS (numba rejects a changed value once
    # its thread pool runs, at the next compile); capped at the pool size it started with.
    import numba

    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    import torch

    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    try:
        if torch.get_num_interop_threads() != n:
            torch.set_num_interop_threads(n)
    except RuntimeError:  # interop threads can only be set before first parallel use
        pass


def available_cpus() -> int:
    """CPUs this process may use (affinity-aware), never less than 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)
