"""What the fine-tune check costs: a unit's BC under ``bc.init: auto``, side by side.

    uv run python -m benchmarks.bench_finetune_check [--trajectories 1600] [--threads 2]

The log is :mod:`benchmarks.bench_log_e2e`'s (the zoo's MountainCar, 1,600 trajectories of up
to 200 steps; 2 seeds, p in {1, 0.5}, the default corruption study), its cells planned from
the true styles (the cost is BC's alone, not the clustering's). Timed in this process, one
variant after another (one warm-up first, so no variant pays the kernels' compilation):
- ``scratch``: the unit's styles were found, every agent trains from scratch (the paper);
- ``doubted, unchecked``: the verdict doubts the styles, every per-cluster agent is fine-tuned
  from No Clustering (``bc.finetune_check: 0``);
- ``doubted, checked``: the same with the check (the default): a trial No Clustering agent and a
  trial fine-tune per per-cluster cell first.
Printed: seconds, and each as a ratio of ``scratch``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from benchmarks.bench_log_e2e import build_log, config
from pcpg_dist.common.devices import set_threads
from pcpg_dist.config import parse_config
from pcpg_dist.domains import contract
from pcpg_dist.pipeline.units import plan_unit
from pcpg_dist.stages.bc import train_cells, train_plan


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trajectories", type=int, default=1600)
    ap.add_argument("--threads", type=int, default=2, help="torch / kernel threads")
    args = ap.parse_args()
    set_threads(args.threads)
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "log.parquet"
        n, steps = build_log(args.trajectories, log)
        cfg = parse_config(config(log, {}))
        (unit,) = contract.units(cfg, contract.generate(cfg, show_progress=False))
        cells = plan_unit(unit, unit.dataset.styles, cfg)
    kinds = sorted({c.spec.kind for c in cells})
    print(f"{n} trajectories, {steps} steps; {len(cells)} cells ({', '.join(kinds)})")
    train_cells(cells[:1], cfg.bc.model_copy(update={"epochs": 1}))  # compile the kernels once
    variants = {
        "scratch": (cfg.bc, False),
        "doubted, unchecked": (cfg.bc.model_copy(update={"finetune_check": 0.0}), True),
        "doubted, checked": (cfg.bc, True),
    }
    seconds = {}
    for name, (bc, doubted) in variants.items():
        t0 = time.perf_counter()
        train_plan(cells, bc, doubted)
        seconds[name] = time.perf_counter() - t0
    print("| variant | s | / scratch |")
    print("|---|---|---|")
    for name, s in seconds.items():
        print(f"| {name} | {s:.1f} | {s / seconds['scratch']:.2f}x |")


if __name__ == "__main__":
    main()
