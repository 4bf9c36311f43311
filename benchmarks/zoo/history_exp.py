"""Do policies that see the time step tell styles apart better? Measured per design game.

    uv run python -m benchmarks.zoo.history_exp mountaincar cartpole     # full size
    uv run python -m benchmarks.zoo.history_exp --ci mountaincar         # a quick look

policy_mix fits k Markov policies pi_c(a | s). Styles that follow a schedule (mountaincar's
rocking back up the left slope for its first 15-34 steps) are not Markov in s, so the heads
cannot tell them apart by what they do in a state. ``clustering.policy_time`` widens the
policies' input by log(1 + t), the step's index in its trajectory. For each game this prints
policy_mix's accuracy and label-free stability (two refits on 80 % subsamples, as the
confidence) with and without it, and the seconds of the fit. Held-out games are refused: they
take no part in design decisions.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.zoo.common import design_games, load_game


def run_game(name: str, ci: bool) -> list[dict]:
    from benchmarks.zoo.check import labelled_dataset
    from pcpg_dist.common.devices import set_threads
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import clustering_metrics
    from pcpg_dist.stages.clustering.confidence import stability
    from pcpg_dist.stages.clustering.step import cluster_once

    set_threads(1)
    game = load_game(name)
    ds = labelled_dataset(name, ci)
    truth = np.asarray(ds.styles, np.int64)
    rows = []
    for with_time in (False, True):
        cfg = ClusterConfig(method="policy_mix", k=len(game.styles), policy_time=with_time)
        t0 = time.perf_counter()
        labels = np.asarray(cluster_once(ds, cfg, 0).labels)
        seconds = time.perf_counter() - t0
        found = stability(ds, cfg, 0, labels, cfg.confidence_runs, cfg.confidence_fraction)
        rows.append({"game": name, "time": with_time, "seconds": seconds,
                     "accuracy": float(clustering_metrics(truth, labels)["accuracy"]),
                     "stability": found["stability"]})  # fmt: skip
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("games", nargs="*", help="design games (default: every design game)")
    parser.add_argument("--ci", action="store_true", help="the CI-size logs")
    args = parser.parse_args()
    games = design_games(args.games, parser.error)
    print("| game | policy_time | accuracy | stability | s (fit) |")
    print("|---|---|---|---|---|")
    for g in games:
        for r in run_game(g, args.ci):
            print(
                f"| {r['game']} | {str(r['time']).lower()} | {r['accuracy']:.3f} | "
                f"{r['stability']:.2f} | {r['seconds']:.0f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
