"""Self-training across views: does a classifier of another view, trained on the default's own
clusters and asked out of fold, move them towards the styles? Measured on design games.

    uv run python -m benchmarks.zoo.build --out zoo_data
    uv run python -m benchmarks.zoo.selftrain_exp zoo_data highway leduc_poker

Start: the default clustering (``cluster`` with ``ClusterConfig(k=...)``). Then, for a few
rounds, each trajectory's label becomes what a model of one view predicts for it when trained
on the other folds' current labels (5-fold ``cross_val_predict``): gradient boosting on
trajectory profiles (the ceiling's view for continuous states and new tasks) or logistic
regression on visit bags. A model cannot predict out of fold what its view does not carry, so
the part of a partition that the view does not support is relabelled by what it does. Printed
each round: accuracy against the styles (never used by the method) and the out-of-fold
agreement with the current labels (label-free). Held-out games are refused.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks.zoo.common import design_games


def view(ds, name: str, seed: int):
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.linear_model import LogisticRegression

    from pcpg_dist.stages.clustering.ceiling import ceiling_features
    from pcpg_dist.stages.clustering.profile import trajectory_profiles

    if name == "profiles":
        model = HistGradientBoostingClassifier(
            max_iter=100, early_stopping=False, random_state=seed
        )
        return trajectory_profiles(ds), model
    return ceiling_features(ds), LogisticRegression(C=1.0, max_iter=2000)


def self_train(x, model, labels: np.ndarray, rounds: int, seed: int, truth):
    from sklearn.model_selection import KFold, cross_val_predict

    from pcpg_dist.stages.clustering import clustering_metrics

    out = []
    for r in range(rounds):
        used = np.unique(labels)
        if len(used) < 2:
            break
        cv = KFold(5, shuffle=True, random_state=seed + r)
        pred = cross_val_predict(model, x, labels, cv=cv, n_jobs=1)
        agree = float((pred == labels).mean())
        labels = pred
        acc = float(clustering_metrics(truth, labels)["accuracy"])
        out.append((r + 1, acc, agree, len(np.unique(labels))))
    return out


def run_game(name: str, root: Path, rounds: int, views: list[str]) -> None:
    from benchmarks.zoo.check import read_unit
    from pcpg_dist.common.devices import set_threads
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import cluster, clustering_metrics

    set_threads(1)
    game, _, ds = read_unit(name, root / name / "labelled")
    k = len(game.styles)
    truth = np.asarray(ds.styles, np.int64)
    t0 = time.perf_counter()
    start = cluster(ds, ClusterConfig(k=k), 0).labels
    acc0 = float(clustering_metrics(truth, start)["accuracy"])
    print(f"| {name} | default | 0 | {acc0:.3f} | | {time.perf_counter() - t0:.0f} |", flush=True)
    for v in views:
        t0 = time.perf_counter()
        x, model = view(ds, v, 0)
        for r, acc, agree, used in self_train(x, model, start.copy(), rounds, 0, truth):
            s = time.perf_counter() - t0
            print(
                f"| {name} | {v} | {r} | {acc:.3f} | {agree:.3f} ({used}) | {s:.0f} |", flush=True
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, help="a zoo built by benchmarks.zoo.build")
    parser.add_argument("games", nargs="*", help="design games (default: every design game)")
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--views", default="profiles,bags")
    args = parser.parse_args()
    print("| game | view | round | accuracy | out-of-fold agreement (clusters) | s |")
    print("|---|---|---|---|---|---|")
    for g in design_games(args.games, parser.error):
        run_game(g, args.root, args.rounds, args.views.split(","))


if __name__ == "__main__":
    main()
