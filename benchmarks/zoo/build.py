"""Write the zoo's step tables and a ready-to-run config per game.

    uv run python -m benchmarks.zoo.build --out zoo_data            # every game, full size
    uv run python -m benchmarks.zoo.build minigrid_empty --ci --out /tmp/zoo

For each game: ``OUT/<game>/labelled/steps.parquet`` (with the true styles, to score against),
``OUT/<game>/unlabelled/steps.parquet`` (style -1 throughout: what a user without labels has)
and ``OUT/<game>/pcpg.yaml`` (``domain: trajectories`` on the labelled table, ``k`` = its styles).
Games build in parallel, one process each.
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import yaml

from benchmarks.zoo.common import episodes, game_names, load_game, step_table


def build(name: str, out: Path, ci: bool = False, seed: int = 0) -> tuple[str, int, int, float]:
    """One game's tables and config; returns (name, trajectories, steps, seconds)."""
    t0 = time.perf_counter()
    game = load_game(name)
    played = episodes(game, ci=ci, seed=seed)
    for labelled in (True, False):
        folder = out / name / ("labelled" if labelled else "unlabelled")
        folder.mkdir(parents=True, exist_ok=True)
        step_table(played, labelled).to_parquet(folder / "steps.parquet", index=False)
    cfg = {
        "name": f"zoo_{name}",
        "domain": "trajectories",
        "trajectories": {"path": "labelled", "score": "return", "n_actions": game.n_actions},
        "clustering": {"k": len(game.styles)},
    }
    (out / name / "pcpg.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    steps = sum(len(ep.actions) for _, ep in played)
    return name, len(played), steps, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("games", nargs="*", help="game folders (default: all)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--ci", action="store_true", help="the small counts CI builds")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    names = args.games or game_names()
    with ProcessPoolExecutor(args.workers) as pool:
        jobs = [pool.submit(build, n, args.out, args.ci, args.seed) for n in names]
        for job in jobs:
            name, n, steps, sec = job.result()
            print(f"{name:<24} {n:6d} trajectories {steps:9d} steps {sec:7.1f} s", flush=True)


if __name__ == "__main__":
    main()
