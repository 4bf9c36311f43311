"""Experiment: trajectory profiles with what the episode's task explains taken out.

    uv run python -m benchmarks.zoo.residual_exp ZOO_DIR [GAME ...] [--held-out]

A trajectory's profile (:func:`~pcpg_dist.stages.clustering.profile.trajectory_profiles`)
mixes its style with its task: on games with a new task every episode the task dominates and
k-means on profiles lands near chance. Here each profile column is regressed (ridge,
cross-fitted over 5 folds, so a trajectory's fit never saw it) on the episode's first state (the
task it set, standardised, PCA to at most 32 dimensions), and k-means runs on the residuals.
Printed per game: k-means on the profiles and on the residuals (standardised, PCA 16, 10
starts), Hungarian accuracy against the labels. Design games by default; ``--held-out`` adds
the held-out ones, reported apart.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from sklearn.cluster import KMeans
from sklearn.decomposition import PCA
from sklearn.linear_model import RidgeCV
from sklearn.model_selection import KFold
from sklearn.preprocessing import StandardScaler

from benchmarks.zoo.check import read_unit
from benchmarks.zoo.common import game_names, load_game
from pcpg_dist.stages.clustering.metrics import clustering_metrics
from pcpg_dist.stages.clustering.profile import trajectory_profiles


def task_of(ds) -> np.ndarray:
    """Each trajectory's first state, its varying features standardised, PCA to <= 32 dims."""
    first = ds.states[ds.offsets[:-1]].astype(np.float64)
    first = first[:, first.std(axis=0) > 1e-9]
    if first.shape[1] == 0:
        return np.zeros((ds.n_trajectories, 1))
    first = StandardScaler().fit_transform(first)
    dims = min(32, first.shape[1], ds.n_trajectories - 1)
    return PCA(dims, random_state=0).fit_transform(first)


def residuals(profiles: np.ndarray, task: np.ndarray, seed: int = 0) -> np.ndarray:
    """Profile minus its cross-fitted ridge prediction from the task."""
    out = np.zeros_like(profiles)
    for fit, held in KFold(5, shuffle=True, random_state=seed).split(profiles):
        model = RidgeCV(alphas=np.logspace(-2, 3, 12)).fit(task[fit], profiles[fit])
        out[held] = profiles[held] - model.predict(task[held])
    return out


def kmeans_accuracy(x: np.ndarray, styles: np.ndarray, k: int, seed: int = 0) -> float:
    x = StandardScaler().fit_transform(x)
    x = PCA(min(16, x.shape[1], len(x) - 1), random_state=seed).fit_transform(x)
    pred = KMeans(k, n_init=10, random_state=seed).fit_predict(x)
    return clustering_metrics(styles, pred)["accuracy"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("zoo", type=Path, help="a folder from benchmarks.zoo.build")
    ap.add_argument("games", nargs="*")
    ap.add_argument("--held-out", action="store_true", help="also the held-out games")
    args = ap.parse_args()
    names = args.games or [g for g in game_names() if args.held_out or not load_game(g).held_out]
    print("| game | held out | profiles | residuals of the first state |")
    print("|---|---|---|---|")
    for name in names:
        game, cfg, ds = read_unit(name, args.zoo / name / "labelled")
        k = len(game.styles)
        prof = trajectory_profiles(ds)
        prof = prof[:, prof.std(axis=0) > 1e-12]
        res = residuals(StandardScaler().fit_transform(prof), task_of(ds))
        a, b = kmeans_accuracy(prof, ds.styles, k), kmeans_accuracy(res, ds.styles, k)
        print(f"| {name} | {'yes' if game.held_out else ''} | {a:.3f} | {b:.3f} |", flush=True)


if __name__ == "__main__":
    main()
