"""Step C of one unit over every CPU: the cells of one continuous log trained as one Ray task
(before: `Step C: BC groups 1/1`, one core busy) and cut into one group per CPU slot (now), side
by side on the same Ray instance, with the trained parameters compared.

    uv run python benchmarks/bench_bc_spread.py [--trajectories 1600] [--steps 200] [--repeats 2]

The log is synthetic and continuous (4-d states, 2 actions, 4 styles: linear controllers with
per-episode noise), the cells those `pcpg run` plans for it (k = 4, seeds 0 and 1, p in {1, 0.5},
No Clustering, no corruption study), trained with the default BC settings.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def synthetic_log(n: int, steps: int, seed: int = 0):
    from pcpg_dist.dataset import Dataset

    rng = np.random.default_rng(seed)
    gains = rng.normal(size=(4, 4))
    trajs, styles = [], []
    for i in range(n):
        style = i % 4
        s = rng.normal(size=4)
        states, actions = [s], []
        for _ in range(steps):
            a = int(gains[style] @ s + rng.normal(scale=0.5) > 0)
            s = 0.9 * s + 0.1 * (2 * a - 1) + rng.normal(scale=0.1, size=4)
            states.append(s)
            actions.append(a)
        trajs.append(
            {
                "states": np.array(states, np.float32),
                "actions": np.array(actions),
                "valid": np.ones((steps + 1, 2), bool),
                "rewards": np.ones(steps),
            }
        )
        styles.append(style)
    return Dataset.from_trajectories(
        "trajectories", "log", 2, trajs, styles=styles, success=np.ones(n, bool)
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trajectories", type=int, default=1600)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()

    import ray

    from pcpg_dist.domains.base import Unit
    from pcpg_dist.domains.defaults import split_trajectories
    from pcpg_dist.orchestration.executors import RayExecutor
    from pcpg_dist.orchestration.ray_pool import init_ray
    from pcpg_dist.pipeline.tasks import train_task
    from pcpg_dist.pipeline.units import plan_unit
    from pcpg_dist.stages.bc import TrainedCells

    ds = synthetic_log(args.trajectories, args.steps)
    init_ray()
    cpus = int(ray.cluster_resources()["CPU"])
    slots = RayExecutor().slots(1)
    _, test = split_trajectories(ds.n_trajectories, 0.2, 0)
    unit = Unit("log", ds, test)
    cfg = _config()
    labels = np.asarray(ds.styles)
    cells = plan_unit(unit, labels, cfg, corruption=False)
    task = ray.remote(num_cpus=1)(train_task)
    shared = ray.put(unit)
    size = -(-len(cells) // slots)
    print(
        f"{ds.n_trajectories} trajectories x {args.steps} steps, {len(cells)} cells; "
        f"{cpus} CPUs, {slots} slots"
    )
    walls: dict[str, list[float]] = {"one group": [], f"{slots} groups": []}
    params = {}
    for _ in range(args.repeats):
        for name, groups in (
            ("one group", [cells]),
            (f"{slots} groups", [cells[g : g + size] for g in range(0, len(cells), size)]),
        ):
            t0 = time.perf_counter()
            got = [
                TrainedCells.from_files([r["files"]])
                for r in ray.get(
                    [
                        task.remote(shared, labels, None, cfg, [c.key for c in g], cfg.bc, 1)
                        for g in groups
                    ]
                )
            ]
            walls[name].append(time.perf_counter() - t0)
            params[name] = {k: np.concatenate([t.params[k] for t in got]) for k in got[0].params}
    for name, w in walls.items():
        print(
            f"{name:>10}: median {statistics.median(w):.1f} s  ({', '.join(f'{x:.1f}' for x in w)})"
        )
    a, b = walls.values()
    print(f"ratio (groups / one group): {statistics.median(b) / statistics.median(a):.2f}")
    one, split = params.values()
    same = all(np.allclose(one[k], split[k], atol=1e-5) for k in one)
    print(f"parameters equal (1e-5): {same}")


def _config():
    from pcpg_dist.config.experiment import ExperimentConfig

    return ExperimentConfig.model_validate(
        {
            "name": "spread",
            "seeds": [0, 1],
            "ranking": {"ps": [1.0, 0.5]},
            "evaluation": {"corruption_levels": [0.0]},
        }
    )


if __name__ == "__main__":
    main()
