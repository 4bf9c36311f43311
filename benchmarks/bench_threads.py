"""Torch training with 1 and 2 threads, with numba's OpenMP pool started first (as `set_threads`
did until 2026-11-29) beside now, each in a fresh process, one after another.

    uv run python -m benchmarks.bench_threads [--steps 300] [--repeats 2]

Why: numba's OpenMP layer loads the system's libgomp before torch does (torch then shares it)
and turns on nested parallel regions in it. Every MKL call inside one of torch's parallel loops
(Adam's sqrt, tanh) then starts a team of new threads. The loop is what policy_mix and the
latent start fit: an MLP over a few thousand rows, full batch, Adam.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

#: the loop policy_mix and the latent start fit: an MLP over 4,096 rows, full batch, Adam, ``steps``
#: of them (a child's code; ``benchmarks.bench_wait_policy`` runs it too)
MLP_LOOP = r"""
import torch
torch.manual_seed(0)
net = torch.nn.Sequential(torch.nn.Linear(64, 64), torch.nn.Tanh(), torch.nn.Linear(64, 5))
opt = torch.optim.Adam(net.parameters())
x = torch.randn(4096, 64)
t = time.perf_counter()
for _ in range(steps):
    loss = net(x).logsumexp(1).mean()
    opt.zero_grad()
    loss.backward()
    opt.step()
"""

CHILD = r"""
import json, os, sys, time
threads, steps, variant = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
if variant == "before":  # set_threads as it was: numba's pool (OpenMP here) started first
    def set_threads(n):
        for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
            os.environ[var] = str(n)
        import numba
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
        import torch  # after numba's pool, as it was: torch then shares its libgomp

        torch.set_num_threads(n)
else:
    from pcpg_dist.common.devices import set_threads
set_threads(1)  # a Ray worker's start (THREAD_ENV, the tests' one thread), then the task's own
set_threads(threads)
"""
CHILD += MLP_LOOP + 'print(json.dumps({"seconds": time.perf_counter() - t, "loss": float(loss)}))\n'


def run(variant: str, threads: int, steps: int) -> dict:
    env = dict(os.environ)
    env.pop("NUMBA_THREADING_LAYER", None)
    if variant == "before":
        env["NUMBA_THREADING_LAYER"] = "omp"  # numba's own choice where tbb is not installed
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(threads), str(steps), variant],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    print(f"{'threads':>7}  {'before s':>8}  {'now s':>6}  {'before / now':>12}  same loss")
    for threads in (1, 2):
        best = {}
        for variant in ("before", "now"):
            runs = [run(variant, threads, args.steps) for _ in range(args.repeats)]
            best[variant] = min(runs, key=lambda r: r["seconds"])
        before, now = best["before"]["seconds"], best["now"]["seconds"]
        same = best["before"]["loss"] == best["now"]["loss"]
        print(f"{threads:>7}  {before:>8.2f}  {now:>6.2f}  {before / now:>12.2f}  {same}")


if __name__ == "__main__":
    main()
