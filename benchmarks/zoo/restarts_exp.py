"""Restarts chosen by stability: does the most stable of several seeds' default clusterings
beat seed 0's? Design games only (held-out games are refused).

    uv run python -m benchmarks.zoo.build --out zoo_data
    uv run python -m benchmarks.zoo.restarts_exp zoo_data highway tictactoe --seeds 0 1 2 3 4

For each game and seed: the default (``bag_auto``, two refits for its confidence) with that seed,
its accuracy against the styles, its stability and its seconds; then, per game, seed 0's accuracy,
the mean over seeds, and the accuracy of the seed whose stability is highest (what a default
that restarts and keeps its most stable fit would give), and the Spearman correlation of
stability with accuracy across the seeds.

    uv run python -m benchmarks.zoo.restarts_exp zoo_data tictactoe --restarts 3 [--held-out]

With ``--restarts N``: the default with ``clustering.restarts: N`` (seed 0), its accuracy,
stability, the restart it kept and its seconds. ``--held-out`` lets held-out games run, to report
them once the design is fixed.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def main() -> None:
    from scipy.stats import spearmanr

    from benchmarks.zoo.check import read_unit
    from benchmarks.zoo.common import design_games
    from pcpg_dist.common.devices import set_threads
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import cluster, clustering_metrics

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=Path, help="a folder built by benchmarks.zoo.build")
    ap.add_argument("games", nargs="+")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--restarts", type=int, default=0)
    ap.add_argument("--held-out", action="store_true", help="report held-out games too")
    args = ap.parse_args()
    set_threads(1)
    games = args.games if args.held_out else design_games(args.games, ap.error)
    if args.restarts:
        for name in games:
            game, _, ds = read_unit(name, args.data / name / "labelled")
            cfg = ClusterConfig(k=len(game.styles), confidence_runs=2, restarts=args.restarts)
            t0 = time.perf_counter()
            result = cluster(ds, cfg, 0)
            m = result.metrics
            print(
                f"{name} restarts {args.restarts}: accuracy "
                f"{clustering_metrics(ds.styles, result.labels)['accuracy']:.3f} stability "
                f"{m['stability']:.3f} kept restart {m.get('restart_kept', 0):.0f} "
                f"({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
        return
    for name in games:
        game, _, ds = read_unit(name, args.data / name / "labelled")
        cfg = ClusterConfig(k=len(game.styles), confidence_runs=2)
        acc, stab = [], []
        for seed in args.seeds:
            t0 = time.perf_counter()
            result = cluster(ds, cfg, seed)
            acc.append(clustering_metrics(ds.styles, result.labels)["accuracy"])
            stab.append(result.metrics.get("stability", float("nan")))
            print(
                f"{name} seed {seed}: accuracy {acc[-1]:.3f} stability {stab[-1]:.3f} "
                f"({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
        best = int(np.nanargmax(stab))
        rho = spearmanr(stab, acc).statistic if len(set(stab)) > 1 else float("nan")
        print(
            f"{name}: seed {args.seeds[0]} {acc[0]:.3f}, mean {np.mean(acc):.3f}, "
            f"most stable {acc[best]:.3f} (seed {args.seeds[best]}), rho {rho:.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
