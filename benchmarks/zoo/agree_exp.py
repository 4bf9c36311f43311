"""Label-free signals that look only at what players do in the same situation (docs/zoo.md,
"Search or objective?"): measured on design games, not adopted.

    uv run python -m benchmarks.zoo.build --out zoo_data
    uv run python -m benchmarks.zoo.agree_exp zoo_data alone highway leduc_poker
    uv run python -m benchmarks.zoo.agree_exp zoo_data em highway leduc_poker

``alone``: (a) action agreement at similar states (nearest steps of other trajectories; a pair
gains where its actions match beyond the neighbourhood's own rate), clustered by a spectral
embedding; (b) action uni-/bi-/tri-gram frequencies, k-means. ``em``: policy_mix's EM started
from (a), (b), a consensus of 15 such partitions and its default start, each final partition
scored by ``benchmarks.zoo.search.partition_scores``. Held-out games are refused.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def agreement(ds, neighbours: int = 16, queries: int = 40_000, index: int = 80_000, seed: int = 0):
    """(S, C) n x n: summed centred action agreement of trajectory i's steps with j's nearest
    steps, and how many such pairs were seen."""
    from sklearn.neighbors import NearestNeighbors

    from pcpg_dist.stages.clustering.policy_network import policy_inputs
    from pcpg_dist.stages.clustering.states import checked_sequences, fit_normaliser

    states, offsets = checked_sequences(ds)
    n = len(offsets) - 1
    s, a, _, traj = (t.numpy() for t in policy_inputs(ds, states, *fit_normaliser(states)))
    rng = np.random.default_rng(seed)
    idx = rng.permutation(len(a))[:index]  # shuffled: ties among equal states fall at random
    q = rng.permutation(len(a))[:queries]
    found = NearestNeighbors(n_neighbors=min(4 * neighbours, len(idx))).fit(s[idx])
    nb = idx[found.kneighbors(s[q], return_distance=False)]
    other = traj[nb] != traj[q][:, None]
    keep = other & (np.cumsum(other, 1) <= neighbours)  # the nearest of other trajectories
    match = (a[nb] == a[q][:, None]).astype(float)
    rate = (match * keep).sum(1) / np.maximum(keep.sum(1), 1)
    ii = np.broadcast_to(traj[q][:, None], nb.shape)[keep]
    jj = traj[nb][keep]
    S, C = np.zeros((n, n)), np.zeros((n, n))
    np.add.at(S, (ii, jj), (match - rate[:, None])[keep])
    np.add.at(C, (ii, jj), 1.0)
    return S, C


def spectral(S, C, k: int, seed: int = 0, norm: str = "degree") -> np.ndarray:
    """k-means on the top k - 1 eigenvectors of the symmetrised agreement."""
    from sklearn.cluster import KMeans

    if norm == "shrink":
        A = (S + S.T) / (C + C.T + 1.0)
    else:
        d = np.sqrt(np.maximum(C.sum(1), 1))
        A = (S + S.T) / d[:, None] / d[None, :]
    w, v = np.linalg.eigh(A)
    top = np.argsort(w)[::-1][: max(k - 1, 1)]
    x = v[:, top] * np.sqrt(np.maximum(w[top], 0))
    x /= np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-12)
    return KMeans(k, n_init=10, random_state=seed).fit_predict(x)


def ngrams(ds, orders=(1, 2)) -> np.ndarray:
    """Per trajectory: the frequencies of its action n-grams, each order summing to 1."""
    a, traj = np.asarray(ds.actions), ds.row_trajectory
    n, na = ds.n_trajectories, int(ds.n_actions)
    out = []
    for o in orders:
        m = len(a) - o + 1
        code, ok = np.zeros(m, np.int64), np.ones(m, bool)
        for j in range(o):
            ok &= (a[j : m + j] >= 0) & (traj[j : m + j] == traj[:m])
            code = code * na + np.maximum(a[j : m + j], 0)
        f = np.zeros((n, na**o))
        np.add.at(f, (traj[:m][ok], code[ok]), 1.0)
        out.append(f / np.maximum(f.sum(1, keepdims=True), 1))
    return np.hstack(out)


def kmeans(x: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
    from sklearn.cluster import KMeans

    x = x[:, x.std(0) > 1e-12]
    return KMeans(k, n_init=10, random_state=seed).fit_predict((x - x.mean(0)) / x.std(0))


def consensus(ds, k: int) -> np.ndarray:
    """Spectral clustering of the co-association of 15 partitions (3 seeds x 5 views)."""
    from sklearn.cluster import KMeans, SpectralClustering

    from pcpg_dist.stages.clustering.policy_mix import counter_summary
    from pcpg_dist.stages.clustering.states import checked_sequences

    states, offsets = checked_sequences(ds)
    parts = []
    for seed in range(3):
        S, C = agreement(ds, seed=seed)
        parts += [
            kmeans(ngrams(ds), k, seed),
            kmeans(ngrams(ds, (1, 2, 3)), k + 2, seed),
            spectral(S, C, k, seed),
            spectral(S, C, k + 2, seed, norm="shrink"),
            KMeans(k + 2, n_init=3, random_state=seed).fit_predict(
                counter_summary(states, offsets)
            ),
        ]
    co = np.mean([p[:, None] == p[None, :] for p in parts], axis=0)
    return SpectralClustering(k, affinity="precomputed", random_state=0).fit_predict(co + 1e-6)


def alone(ds, k: int, truth: np.ndarray) -> str:
    from pcpg_dist.stages.clustering import clustering_metrics

    out = []
    for nb in (8, 32):
        S, C = agreement(ds, neighbours=nb)
        for norm in ("shrink", "degree"):
            acc = clustering_metrics(truth, spectral(S, C, k, norm=norm))["accuracy"]
            out.append(f"agreement K={nb} {norm} {acc:.3f}")
    for orders in ((1, 2), (1, 2, 3)):
        acc = clustering_metrics(truth, kmeans(ngrams(ds, orders), k))["accuracy"]
        out.append(f"n-grams {orders} {acc:.3f}")
    return "; ".join(out)


def as_em_start(ds, k: int, truth: np.ndarray) -> str:
    import torch

    from benchmarks.zoo.search import partition_scores
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import clustering_metrics
    from pcpg_dist.stages.clustering.policy_mix import _fit_policy_mix
    from pcpg_dist.stages.clustering.states import checked_sequences

    cfg = ClusterConfig(method="policy_mix", k=k)
    states, offsets = checked_sequences(ds)
    S, C = agreement(ds, neighbours=32)
    starts = {
        "n-grams": kmeans(ngrams(ds), k),
        "agreement": spectral(S, C, k),
        "consensus": consensus(ds, k),
        "default": None,
    }
    out = []
    for name, start in starts.items():
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(0)
            labels, *_ = _fit_policy_mix(ds, states, offsets, cfg, 0, {}, start=start)
        acc = clustering_metrics(truth, labels)["accuracy"]
        sc = partition_scores(ds, labels, k, 300)
        out.append(f"{name} -> {acc:.3f} (fit {sc['fit']:.4f}, held out {sc['held_out']:.4f})")
    sc = partition_scores(ds, truth, k, 300)
    out.append(f"the styles (fit {sc['fit']:.4f}, held out {sc['held_out']:.4f})")
    return "; ".join(out)


def main() -> None:
    from benchmarks.zoo.check import read_unit
    from benchmarks.zoo.common import design_games
    from pcpg_dist.common.devices import set_threads

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path, help="benchmarks.zoo.build --out")
    ap.add_argument("mode", choices=("alone", "em"))
    ap.add_argument("games", nargs="+")
    args = ap.parse_args()
    set_threads(1)
    for name in design_games(args.games, ap.error):
        game, _, ds = read_unit(name, args.root / name / "labelled")
        truth, k = np.asarray(ds.styles), len(game.styles)
        run = alone if args.mode == "alone" else as_em_start
        print(f"{name}: {run(ds, k, truth)}", flush=True)


if __name__ == "__main__":
    main()
