"""`set_threads` and OpenMP: torch's parallel loops must not nest parallel regions (each nested
MKL call then started new threads: training with two threads ran 3-4x slower)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

CHILD = r"""
import ctypes, json
from pcpg_dist.common.devices import set_threads
set_threads(1)
import numba, numpy as np

@numba.njit(parallel=True)  # a plugin's own parallel numba code, run before torch's threads grow
def total(x):
    s = 0.0
    for i in numba.prange(x.shape[0]):
        s += x[i]
    return s

total(np.ones(64))
set_threads(2)
import torch
net = torch.nn.Sequential(torch.nn.Linear(16, 16), torch.nn.Tanh(), torch.nn.Linear(16, 3))
opt = torch.optim.Adam(net.parameters())
for _ in range(3):
    loss = net(torch.randn(2048, 16)).logsumexp(1).mean()
    opt.zero_grad(); loss.backward(); opt.step()
from threadpoolctl import threadpool_info
runtimes = {}
for info in threadpool_info():
    if info["internal_api"] == "openmp":
        lib = ctypes.CDLL(info["filepath"])
        runtimes[info["filepath"]] = [lib.omp_get_nested(), lib.omp_get_max_active_levels()]
print(json.dumps({"torch_threads": torch.get_num_threads(), "runtimes": runtimes}))
"""


def test_no_openmp_runtime_nests_parallel_regions_after_set_threads():
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_THREADING_LAYER"}
    out = subprocess.run(
        [sys.executable, "-c", CHILD], env=env, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr[-2000:]
    seen = json.loads(out.stdout.strip().splitlines()[-1])
    assert seen["torch_threads"] == 2 and seen["runtimes"], seen
    nesting = {path: v for path, v in seen["runtimes"].items() if v[0] and v[1] > 1}
    assert not nesting, f"nested parallel regions on in {nesting}"


def test_a_drivers_openmp_wait_policy_goes_to_every_ray_worker(monkeypatch):
    """Where the driver's environment sets OpenMP's wait policy, every Ray worker's environment has
    it beside the one-thread defaults (on a cluster the workers do not inherit the driver's; the
    two-node test in tests/ops/test_ray_cluster.py runs it for real); where unset, nothing is added."""
    from pcpg_dist.common.devices import THREAD_ENV, worker_env
    from pcpg_dist.orchestration.ray_pool import package_runtime_env

    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    monkeypatch.delenv("GOMP_SPINCOUNT", raising=False)
    env = worker_env()
    assert env == {**THREAD_ENV, "OMP_WAIT_POLICY": "ACTIVE"}
    assert package_runtime_env()["env_vars"] == env
    monkeypatch.delenv("OMP_WAIT_POLICY")
    assert worker_env() == THREAD_ENV


def test_numpy_work_takes_the_threads_a_task_was_given(monkeypatch):
    from pcpg_dist.common.devices import available_cpus, set_threads, thread_budget

    monkeypatch.setenv("OMP_NUM_THREADS", "1")  # set_threads writes it; restored after the test
    set_threads(2)
    try:
        assert thread_budget() == min(2, available_cpus())
    finally:
        set_threads(1)
    assert thread_budget() == 1
    monkeypatch.setenv("OMP_NUM_THREADS", "")  # unset or unreadable: the process's CPUs
    assert thread_budget() == available_cpus()
    monkeypatch.setenv("OMP_NUM_THREADS", "4096")  # never more than the CPUs
    assert thread_budget() == available_cpus()
