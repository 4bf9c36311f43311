"""Experiment: what a player does beyond what any player would do in the same state.

    uv run python -m benchmarks.zoo.deviation_exp ZOO_DIR [GAME ...]

On games with a new task every episode, the states a trajectory visits follow its task, and
clusterers that look at states (or at policies over them) split by task. Here one population
policy pi_0(a | s), fitted to every player (gradient boosting on the states, cross-fitted over
two halves of the trajectories, so a trajectory is scored by a policy that never saw it), says
what the average player does in each state; a trajectory's *deviation* is, per step,
onehot(a_t) - pi_0(. | s_t): what this player did beyond that. The task sets which states come
up, not what the deviations are, so their means should follow the style.

Features per trajectory (k-means, standardised, 10 starts), Hungarian accuracy against the
labels:
- ``mean``: the mean deviation over its steps (n_actions numbers);
- ``regions``: the mean deviation within each of 8 regions of the state space (k-means on the
  states), weighted by how often the trajectory was there (8 x n_actions numbers);
- ``surprise``: mean and 10/50/90 % quantiles of -log pi_0(a_t | s_t) (how unusual its play is).

Design games only: it refuses held-out games.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from sklearn.cluster import KMeans, MiniBatchKMeans
from sklearn.ensemble import HistGradientBoostingClassifier
from sklearn.preprocessing import StandardScaler

from benchmarks.zoo.check import read_unit
from benchmarks.zoo.common import design_games
from pcpg_dist.stages.clustering.metrics import clustering_metrics

SAMPLE = 40_000  # steps a half's population policy is fitted to, at most
REGIONS = 8


def population_probs(ds, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(rows, probs): the steps with an action and pi_0(. | s) of each, cross-fitted."""
    rows = np.flatnonzero(ds.actions >= 0)
    traj = ds.row_trajectory[rows]
    rng = np.random.default_rng(seed)
    half = rng.permutation(ds.n_trajectories) % 2
    probs = np.zeros((len(rows), ds.n_actions))
    x = ds.states[rows].astype(np.float32)
    y = ds.actions[rows]
    for h in (0, 1):
        fit = np.flatnonzero(half[traj] != h)
        if len(fit) > SAMPLE:
            fit = rng.choice(fit, SAMPLE, replace=False)
        model = HistGradientBoostingClassifier(max_iter=100, random_state=seed)
        model.fit(x[fit], y[fit])
        score = np.flatnonzero(half[traj] == h)
        probs[np.ix_(score, model.classes_)] = model.predict_proba(x[score])
    return rows, probs


def features(ds, rows: np.ndarray, probs: np.ndarray) -> dict[str, np.ndarray]:
    n, a = ds.n_trajectories, ds.n_actions
    traj = ds.row_trajectory[rows]
    dev = -probs
    dev[np.arange(len(rows)), ds.actions[rows]] += 1.0
    count = np.maximum(np.bincount(traj, minlength=n), 1)[:, None]
    mean = np.zeros((n, a))
    np.add.at(mean, traj, dev)
    mean /= count
    x = StandardScaler().fit_transform(ds.states[rows].astype(np.float64))
    x = x[:, np.isfinite(x).all(axis=0)]
    region = MiniBatchKMeans(REGIONS, random_state=0, n_init=3).fit_predict(x)
    reg = np.zeros((n, REGIONS, a))
    np.add.at(reg, (traj, region), dev)
    reg /= count[:, :, None]
    nll = -np.log(np.maximum(probs[np.arange(len(rows)), ds.actions[rows]], 1e-6))
    order = np.argsort(traj, kind="stable")
    cuts = np.searchsorted(traj[order], np.arange(n + 1))
    surprise = np.zeros((n, 4))
    for i in range(n):
        v = nll[order[cuts[i] : cuts[i + 1]]]
        if len(v):
            surprise[i] = [v.mean(), *np.quantile(v, (0.1, 0.5, 0.9))]
    return {"mean": mean, "regions": reg.reshape(n, -1), "surprise": surprise}


def kmeans_accuracy(x: np.ndarray, styles: np.ndarray, k: int) -> float:
    x = StandardScaler().fit_transform(x[:, x.std(axis=0) > 1e-12])
    pred = KMeans(k, n_init=10, random_state=0).fit_predict(x)
    return clustering_metrics(styles, pred)["accuracy"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("zoo", type=Path, help="a folder from benchmarks.zoo.build")
    ap.add_argument("games", nargs="*")
    args = ap.parse_args()
    names = design_games(args.games, ap.error)
    print("| game | mean | regions | surprise | mean + regions |")
    print("|---|---|---|---|---|")
    for name in names:
        game, _, ds = read_unit(name, args.zoo / name / "labelled")
        k = len(game.styles)
        f = features(ds, *population_probs(ds))
        f["mean + regions"] = np.hstack([f["mean"], f["regions"]])
        accs = [kmeans_accuracy(f[c], ds.styles, k) for c in ("mean", "regions", "surprise")]
        accs.append(kmeans_accuracy(f["mean + regions"], ds.styles, k))
        print(f"| {name} | " + " | ".join(f"{v:.3f}" for v in accs) + " |", flush=True)


if __name__ == "__main__":
    main()
