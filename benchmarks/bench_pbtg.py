"""Time the full paper GridWorld data: 20 Q-learners x 20000 episodes + 160,000 trajectories.

Target (issue 2): <= 60 s on a 2-core laptop CPU. Prints the figure with and without Ray so the
cost of the fan-out itself is visible. Run: ``uv run python benchmarks/bench_pbtg.py``.
"""

from __future__ import annotations

import time
from pathlib import Path

from pcpg_dist.config import load_config
from pcpg_dist.domains.gridworld.domain import gridworld_layouts
from pcpg_dist.domains.gridworld.pbtg import generate_pair
from pcpg_dist.orchestration.ray_pool import fan_out, init_ray
from pcpg_dist.stages.data import generate

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    cfg = load_config(ROOT / "experiments" / "gridworld_paper.yaml")
    layouts = gridworld_layouts(cfg)
    generate_pair(
        layouts[0],
        0,
        cfg.pbtg.model_copy(
            update={"episodes": 10, "trajectories_per_style": 10, "dataset_per_style": 10}
        ),
        0,
    )  # JIT warm-up
    t0 = time.perf_counter()
    for layout in layouts:
        for r in range(4):
            generate_pair(layout, r, cfg.pbtg, cfg.seed)
    sequential = time.perf_counter() - t0
    t0 = time.perf_counter()
    init_ray()
    ray_start = time.perf_counter() - t0
    t0 = time.perf_counter()
    generate(cfg, False, fan_out)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    generate(cfg, False, fan_out)
    warm = time.perf_counter() - t0
    n = cfg.pbtg.trajectories_per_style * len(layouts) * 4
    print(f"PBTG paper data: 20 Q-learners x {cfg.pbtg.episodes} episodes + {n} trajectories")
    print(f"  in-process, one core, after JIT : {sequential:6.1f} s")
    print(f"  Ray start                       : {ray_start:6.1f} s")
    print(f"  Ray, cold workers (JIT, imports): {first:6.1f} s")
    print(f"  Ray, warm workers               : {warm:6.1f} s   (target <= 60 s)")


if __name__ == "__main__":
    main()
