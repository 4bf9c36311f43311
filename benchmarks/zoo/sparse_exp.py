"""Experiment: sparse k-means on trajectory profiles (Witten & Tibshirani, 2010).

    uv run python -m benchmarks.zoo.sparse_exp ZOO_DIR [GAME ...]

A trajectory's profile has a few hundred columns; on games with a new task every episode most of
them follow the task, and plain k-means on all of them lands near chance. Sparse k-means weighs
the columns while it clusters: it alternates k-means on the weighted columns with weights
``w = S(a, delta) / |S(a, delta)|_2`` (``a`` each column's between-cluster sum of squares,
``S`` soft thresholding, ``delta`` set so that ``|w|_1 = s``), so only the columns the clusters
separate keep weight. The bound ``s`` is chosen without labels by the gap statistic of the
paper: the weighted between-cluster sum against that on copies whose columns are permuted
independently.

Printed per game: k-means on the standardised profiles, sparse k-means at each bound, the bound
the gap statistic chooses and its accuracy (Hungarian accuracy against the labels). Design games
only: it refuses held-out games.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from sklearn.cluster import KMeans
from sklearn.preprocessing import StandardScaler

from benchmarks.zoo.check import read_unit
from benchmarks.zoo.common import design_games
from pcpg_dist.stages.clustering.metrics import clustering_metrics
from pcpg_dist.stages.clustering.profile import trajectory_profiles

BOUNDS = (1.5, 2.0, 3.0, 4.0, 6.0, 9.0)


def _soft_weights(a: np.ndarray, s: float) -> np.ndarray:
    """w = S(a, delta) / |S(a, delta)|_2 with delta >= 0 the least that keeps |w|_1 <= s."""
    a = np.maximum(a, 0.0)
    w = a / max(np.linalg.norm(a), 1e-12)
    if w.sum() <= s:
        return w
    lo, hi = 0.0, float(a.max())
    for _ in range(60):
        mid = (lo + hi) / 2
        t = np.maximum(a - mid, 0.0)
        w = t / max(np.linalg.norm(t), 1e-12)
        lo, hi = (mid, hi) if w.sum() > s else (lo, mid)
    t = np.maximum(a - hi, 0.0)
    return t / max(np.linalg.norm(t), 1e-12)


def _bcss(x: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Each column's between-cluster sum of squares (x centred)."""
    out = np.zeros(x.shape[1])
    for c in np.unique(labels):
        rows = x[labels == c]
        out += len(rows) * rows.mean(axis=0) ** 2
    return out


def sparse_kmeans(x: np.ndarray, k: int, s: float, seed: int = 0, rounds: int = 8):
    """(labels, weights, objective): sparse k-means on standardised columns ``x``."""
    w = np.full(x.shape[1], 1.0 / np.sqrt(x.shape[1]))
    labels = None
    for _ in range(rounds):
        new = KMeans(k, n_init=10, random_state=seed).fit_predict(x * np.sqrt(w))
        w_new = _soft_weights(_bcss(x, new), s)
        done = labels is not None and np.array_equal(new, labels)
        labels, w = new, w_new
        if done:
            break
    return labels, w, float(w @ _bcss(x, labels))


def gap_choice(x: np.ndarray, k: int, seed: int = 0, perms: int = 5):
    """(bound, gaps): the bound with the largest gap statistic over BOUNDS."""
    rng = np.random.default_rng(seed)
    copies = [np.column_stack([rng.permutation(c) for c in x.T]) for _ in range(perms)]
    gaps = []
    for s in BOUNDS:
        obj = sparse_kmeans(x, k, s, seed)[2]
        null = [np.log(sparse_kmeans(c, k, s, seed)[2]) for c in copies]
        gaps.append(np.log(obj) - float(np.mean(null)))
    return BOUNDS[int(np.argmax(gaps))], gaps


def _accuracy(styles: np.ndarray, labels: np.ndarray) -> float:
    return clustering_metrics(styles, labels)["accuracy"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("zoo", type=Path, help="a folder from benchmarks.zoo.build")
    ap.add_argument("games", nargs="*")
    args = ap.parse_args()
    names = design_games(args.games, ap.error)
    head = " | ".join(f"s={s:g}" for s in BOUNDS)
    print(f"| game | k-means | {head} | gap's bound | its accuracy |")
    print("|---" * (len(BOUNDS) + 4) + "|")
    for name in names:
        game, _, ds = read_unit(name, args.zoo / name / "labelled")
        k = len(game.styles)
        prof = trajectory_profiles(ds)
        x = StandardScaler().fit_transform(prof[:, prof.std(axis=0) > 1e-12])
        plain = _accuracy(ds.styles, KMeans(k, n_init=10, random_state=0).fit_predict(x))
        per = [_accuracy(ds.styles, sparse_kmeans(x, k, s)[0]) for s in BOUNDS]
        s, _ = gap_choice(x, k)
        chosen = per[BOUNDS.index(s)]
        cells = " | ".join(f"{a:.3f}" for a in per)
        print(f"| {name} | {plain:.3f} | {cells} | {s:g} | {chosen:.3f} |", flush=True)


if __name__ == "__main__":
    main()
