"""Is the policy classifier's shortfall from the ceiling its model class, or its budget and
inputs? The supervised panel's policy classifier, varied. Design games only.

    uv run python -m benchmarks.zoo.policy_class_exp [GAME ...] [--variants inputs budget]

On seven zoo games k policies of policy_mix's kind, given the styles, classify 3.7-12.9 points
below the ceiling (docs/zoo.md, "Why the gap remains"): the gap's model-class part. Two ways it
could be smaller than it reads, each measured with the panel's own cross-validation (5 folds,
seed 0, one torch thread):

- ``budget``: the classifier trained 4x longer (1,200 Adam steps against 300) and 4x wider (128
  units against 32): if it gained, the part would be the budget's, not the model class's.
- ``inputs``: the policies also see the trajectory's history, the previous action (one-hot) and
  the share of each action so far: styles that are not Markov in the state (a route taken
  once decided) show in them.

``label_free``: the default clustering (``bag_auto``, seed 0, its confidence refits) of the log
whose states also hold the previous action, beside the one table's seed 0 without it
(``benchmarks/zoo/confidence_results.json``): what a user who adds that column gets.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from benchmarks.zoo.common import design_games

#: the design games whose model-class part is over 3 points (the nineteenth session)
SHORT = ("highway", "minigrid_empty", "minigrid_fourrooms", "tictactoe")


def with_history(ds, shares: bool):
    """``ds`` whose states also hold the previous action one-hot (zeros on a trajectory's first
    row) and, with ``shares``, the share of each action among the trajectory's earlier steps."""
    acts = np.asarray(ds.actions)
    prev = np.full(len(acts), -1)
    prev[1:] = acts[:-1]
    prev[ds.offsets[:-1]] = -1
    onehot = np.zeros((len(acts), ds.n_actions), np.float32)
    onehot[np.flatnonzero(prev >= 0), prev[prev >= 0]] = 1
    extra = [onehot]
    if shares:
        cum = np.cumsum(onehot, 0)
        first = ds.offsets[:-1][ds.row_trajectory]
        cum = cum - cum[first] + onehot[first]  # the counts within the trajectory
        extra.append(cum / np.maximum(ds.row_step, 1)[:, None])
    states = np.hstack([ds.states, *extra]).astype(np.float32)
    names = ds.feature_names
    if names:
        names = names + tuple(f"history_{i}" for i in range(states.shape[1] - len(names)))
    return dataclasses.replace(ds, states=states, feature_names=names)


def classifier(ds, steps: int = 0, hidden: int = 0) -> float:
    """The panel's policy classifier's cross-validated accuracy on ``ds``, at this budget (0:
    the panel's own)."""
    from sklearn.model_selection import StratifiedKFold

    from pcpg_dist.stages.clustering.ceiling import _policy_likelihood

    cv = StratifiedKFold(n_splits=5, shuffle=True, random_state=0)
    return _policy_likelihood(ds, cv, 0, steps=steps, hidden=hidden)


def label_free(name: str, ds, was: float) -> str:
    """The default's accuracy on ``ds`` with the previous action among its states, beside
    ``was``, the one table's seed 0 without it."""
    from benchmarks.zoo.common import load_game
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import cluster, clustering_metrics

    k = len(load_game(name).styles)
    labels = cluster(with_history(ds, False), ClusterConfig(k=k), 0).labels
    got = clustering_metrics(ds.styles, labels)["accuracy"]
    return f"default {was:.3f} -> {got:.3f} with the previous action"


def main() -> None:
    from benchmarks.zoo.check import labelled_dataset
    from pcpg_dist.common.devices import set_threads

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("games", nargs="*", default=list(SHORT))
    ap.add_argument("--variants", nargs="+", default=["inputs", "budget"])
    args = ap.parse_args()
    set_threads(1)
    rows = json.loads(Path("benchmarks/zoo/confidence_results.json").read_text())["rows"]
    table = {r["game"]: r["accuracy"] for r in rows if r["seed"] == 0}  # the one table's seed 0
    for name in design_games(args.games, ap.error):
        ds = labelled_dataset(name, False)
        row = {}
        if {"inputs", "budget"} & set(args.variants):
            row["as in the panel"] = classifier(ds)
        if "inputs" in args.variants:
            row["+ previous action"] = classifier(with_history(ds, False))
            row["+ previous action, action shares"] = classifier(with_history(ds, True))
        if "budget" in args.variants:
            row["1200 steps"] = classifier(ds, 1200)
            row["1200 steps, 128 units"] = classifier(ds, 1200, 128)
        if row:
            print(name + ": " + ", ".join(f"{k} {v:.3f}" for k, v in row.items()), flush=True)
        if "label_free" in args.variants:
            print(f"{name}: {label_free(name, ds, table[name])}", flush=True)


if __name__ == "__main__":
    main()
