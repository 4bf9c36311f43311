"""Time a whole `pcpg run` from scratch (default: the paper's GridWorld protocol).

Issue target: experiments/gridworld_paper.yaml — 5 environments, 4 seeds, all p, No Clustering,
corruption study at 6 levels, rollouts, tracking and report — in <= 10 minutes on a 2-core CPU.
Prints wall time per stage and where it goes. Run: ``uv run python benchmarks/bench_run.py``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from pcpg_dist.api.run import run_experiment
from pcpg_dist.config import load_config
from pcpg_dist.orchestration.ray_pool import init_ray

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("config", nargs="?", default=str(ROOT / "experiments" / "gridworld_paper.yaml"))
    args = ap.parse_args()
    cfg = load_config(args.config)
    t0 = time.perf_counter()
    init_ray()
    ray_start = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        t1 = time.perf_counter()
        result = run_experiment(
            cfg,
            workdir=Path(tmp) / "runs",
            tracking_uri=f"sqlite:///{tmp}/mlflow.db",
            show_progress=False,
            command=f"pcpg run {args.config}",
        )
        total = time.perf_counter() - t1
    print(f"{cfg.name}: {len(result.clustering)} environment(s), seeds {cfg.seeds}")
    print(f"  {'ray start':<10} {ray_start:7.1f} s")
    for stage, sec in result.stage_seconds.items():
        print(f"  {stage:<10} {sec:7.1f} s")
    print(f"  {'total':<10} {total + ray_start:7.1f} s   (target for gridworld_paper: <= 600 s)")


if __name__ == "__main__":
    main()
