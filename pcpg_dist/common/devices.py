"""Ray and thread-count helpers shared by the runner, the tests and the stages' Ray wrappers.

Stages never import Ray; the runner wraps them. Torch in a reused Ray worker keeps the thread count
of its first task, and oversubscribed torch on 2 cores was measured ~100x slower, so every task
calls :func:`set_threads` with the CPUs it was given before touching torch.
"""

from __future__ import annotations

import os
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch


#: every Ray worker starts at one thread; a task then takes the CPUs it was given (set_threads)
THREAD_ENV = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "TOKENIZERS_PARALLELISM": "false"}
#: OpenMP's wait policy, where the driver's environment sets it, reaches every worker too (on a
#: cluster, where workers do not inherit the driver's environment): on a machine that other work
#: shares, ``OMP_WAIT_POLICY=PASSIVE`` keeps a task's two torch threads from spinning on a busy
#: core (docs/scale.md, "Threads on a shared machine")
FORWARDED_ENV = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")


def worker_env() -> dict[str, str]:
    """The environment every Ray worker of a run gets: :data:`THREAD_ENV`, and the driver's
    :data:`FORWARDED_ENV` where set."""
    return {**THREAD_ENV, **{k: os.environ[k] for k in FORWARDED_ENV if k in os.environ}}


def set_threads(n: int) -> None:
    """Limit torch (and BLAS via env vars for subprocesses) to ``n`` threads in this process."""
    n = max(1, int(n))
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = str(n)
    _quiet_numba_layer()
    import torch

    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    try:
        if torch.get_num_interop_threads() != n:
            torch.set_num_interop_threads(n)
    except RuntimeError:  # interop threads can only be set before first parallel use
        pass


def _quiet_numba_layer() -> None:
    """Keep numba's OpenMP thread pool out of this process: nothing here runs numba in parallel
    (the BC kernel runs one ``nogil`` call per Python thread). Started, that pool loads the
    system's libgomp before torch does (torch then shares it) and turns on nested parallel
    regions in it: every MKL call inside one of torch's parallel loops then starts new threads,
    and training with two torch threads ran 3-4x slower (docs/scale.md, "Threads"). A user's
    ``NUMBA_THREADING_LAYER`` still decides.
    """
    os.environ.setdefault("NUMBA_THREADING_LAYER", "workqueue")
    numba = sys.modules.get("numba")
    if numba is not None and numba.config.THREADING_LAYER == "default":
        numba.config.THREADING_LAYER = "workqueue"


def thread_budget() -> int:
    """The threads this process's numpy work may use: what :func:`set_threads` gave it (a task's
    CPUs) or the user's ``OMP_NUM_THREADS``, never more than its CPUs; else its CPUs."""
    try:
        return max(1, min(int(os.environ.get("OMP_NUM_THREADS", "")), available_cpus()))
    except ValueError:
        return available_cpus()


def available_cpus() -> int:
    """CPUs this process may use (affinity-aware), never less than 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


def resolve_device(name: str, key: str) -> torch.device:
    """``cpu``, ``cuda`` or ``auto`` (a GPU where this process sees one) as a torch device.

    Under Ray the runner makes a stage whose ``key`` is not ``cpu`` ask for GPUs, so that Ray
    places its tasks on nodes that have one and shares each GPU among a bounded number of them.
    """
    import torch

    from pcpg_dist.common.errors import ConfigError

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"{key} is 'cuda' but torch sees no GPU here; use 'cpu' or 'auto'")
    return torch.device(name)


def stage_gpus(device: str, gpus_per_task: float, node_gpus: float, key: str) -> float:
    """GPUs each Ray task of a stage asks for: ``gpus_per_task`` where ``device`` (the stage's
    setting, named ``key``) is ``cuda``, or ``auto`` on a cluster with GPUs; else none.
    ``node_gpus``: the most GPUs one live node has (a task runs on one node).

    ``cuda`` on a cluster without a GPU fails here, in one line, before anything starts.
    """
    from pcpg_dist.common.errors import ConfigError

    if device == "cpu" or (device == "auto" and node_gpus <= 0):
        return 0.0
    if node_gpus <= 0:
        raise ConfigError(
            f"{key} is 'cuda' but no Ray node has a GPU; use 'cpu', or 'auto' "
            "(a GPU where the cluster has one)"
        )
    if gpus_per_task > node_gpus:
        raise ConfigError(
            f"runner.gpus_per_task: {gpus_per_task:g} GPUs per task, but the largest "
            f"Ray node has {node_gpus:g}; set it to at most {node_gpus:g}"
        )
    return float(gpus_per_task)
