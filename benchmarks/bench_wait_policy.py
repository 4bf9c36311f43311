"""Two torch threads on a machine where another process holds a core: OpenMP's wait policy, side by
side.

    uv run python -m benchmarks.bench_wait_policy [--policies default passive 10000] [--repeats 3]

A task given two CPUs runs torch on two threads. Torch's OpenMP threads spin at the end of every
parallel region, waiting for the others; where another process holds one of the two cores (a
second test worker, a browser), the spinning thread keeps its core while the one it waits for
queues for the other, and every small parallel region costs a scheduler time slice. The policies:
``default`` (libgomp's own: spin about 300,000 times, then sleep), ``passive`` (sleep at once,
``OMP_WAIT_POLICY=PASSIVE``) and a number (spin that many times, ``GOMP_SPINCOUNT``). Each run is a
fresh process (the policy is read when torch loads its OpenMP runtime) that starts at one thread,
as a Ray worker does, then takes two: the loop policy_mix and the latent start fit (an MLP over
4,096 rows, full batch, Adam), and one policy_mix fit of the zoo's cartpole (or, given a zoo
game's name, its default clustering, as ``benchmarks.zoo.speed`` times it). Idle, then with one
core held by a busy loop; the best of ``--repeats``. The policy changes no value: the losses and
labels are printed to show it.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import textwrap

from benchmarks.bench_threads import MLP_LOOP

CHILD = (
    r"""
import json, sys, time
work = sys.argv[1]
from pcpg_dist.common.devices import set_threads
set_threads(1)
set_threads(2)
if work == "mlp":
    steps = 600
"""
    + textwrap.indent(MLP_LOOP + "value = float(loss)\n", "    ")
    + r"""
else:  # policy_mix: one fit of cartpole; a zoo game's name: its default clustering (zoo.speed's)
    import hashlib
    from benchmarks.zoo.check import labelled_dataset
    from benchmarks.zoo.common import load_game
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import cluster
    from pcpg_dist.stages.clustering.step import cluster_once
    game = "cartpole" if work == "policy_mix" else work
    ds = labelled_dataset(game, False)
    k = len(load_game(game).styles)
    t = time.perf_counter()
    if work == "policy_mix":
        labels = cluster_once(ds, ClusterConfig(method="policy_mix", k=k), 0).labels
    else:
        labels = cluster(ds, ClusterConfig(k=k), 0).labels
    value = hashlib.sha256(labels.tobytes()).hexdigest()[:12]
print(json.dumps({"seconds": time.perf_counter() - t, "value": value}))
"""
)


def policy_env(policy: str) -> dict[str, str]:
    """The environment a run of ``policy`` adds (nothing for libgomp's default)."""
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    if policy == "passive":
        env["OMP_WAIT_POLICY"] = "PASSIVE"
    elif policy != "default":
        env["GOMP_SPINCOUNT"] = str(int(policy))
    return env | {"RAY_ENABLE_UV_RUN_RUNTIME_ENV": "0"}


def timed(work: str, policy: str) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", CHILD, work],
        capture_output=True,
        text=True,
        check=True,
        env=policy_env(policy),
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policies", nargs="+", default=["default", "passive", "10000"])
    ap.add_argument(
        "--work", nargs="+", default=["mlp", "policy_mix"], help="mlp, policy_mix or a zoo game"
    )
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    print("| work | machine | " + " | ".join(args.policies) + " | value (same in every column) |")
    print("|---|---|" + "---|" * (len(args.policies) + 1))
    for work in args.work:
        for busy in (False, True):
            burner = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if busy else None
            try:
                runs = {p: [timed(work, p) for _ in range(args.repeats)] for p in args.policies}
            finally:
                if burner is not None:
                    burner.kill()
                    burner.wait()
            values = {r["value"] for rs in runs.values() for r in rs}
            cells = [f"{min(r['seconds'] for r in runs[p]):.2f} s" for p in args.policies]
            where = "one core busy" if busy else "idle"
            same = next(iter(values)) if len(values) == 1 else f"DIFFER: {sorted(values)}"
            print(f"| {work} | {where} | " + " | ".join(cells) + f" | {same} |", flush=True)


if __name__ == "__main__":
    main()
