"""Does the style latent hold the styles, and does it carry the episode's task? Design games only.

    uv run python -m benchmarks.zoo.latent_probe_exp ZOO_DIR [GAME ...] [--seed 0] [--set KEY=VALUE]

policy_mix's default start fits a style latent per trajectory (the consensus of eight fits on
small logs, :mod:`pcpg_dist.stages.clustering.latent_start`). Where it falls short of the
ceiling, either the latents hold the styles and k-means misses them, or they do not hold them.
And on games with a new task every episode the latents may carry the task. Per game, over the
fits of the default plan:

- ``probe``: a logistic regression given the true styles, 5-fold cross-validated, on each fit's
  latents (what a supervised read of the latent reaches; labels used only here);
- ``task R2``: how much of the latents a ridge regression on the episode's first state (the
  task the environment set, standardised, PCA to at most 32 dimensions) explains, cross-fitted
  over 5 folds (a trajectory's prediction never saw it);
- k-means on the latents and on their residuals after that regression, each fit and the
  consensus, then policy_mix's EM from either consensus (accuracy against the labels).
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np


def first_states(states: np.ndarray, offsets: np.ndarray) -> np.ndarray | None:
    """Each trajectory's first state, its varying columns standardised, PCA to <= 32."""
    from sklearn.decomposition import PCA
    from sklearn.preprocessing import StandardScaler

    x = states[offsets[:-1]].astype(np.float64)
    x = x[:, x.std(0) > 0]
    if x.shape[1] == 0:
        return None  # every episode starts alike: a fixed task
    x = StandardScaler().fit_transform(x)
    return PCA(min(32, x.shape[1], len(x) - 1), random_state=0).fit_transform(x)


def residuals(mu: np.ndarray, s0: np.ndarray | None, seed: int) -> tuple[np.ndarray, float]:
    """(mu less its cross-fitted ridge prediction from ``s0``, the share of mu's variance that
    prediction explains)."""
    from sklearn.linear_model import RidgeCV
    from sklearn.model_selection import KFold

    if s0 is None:
        return mu, 0.0
    out = np.empty_like(mu)
    for train, test in KFold(5, shuffle=True, random_state=seed).split(mu):
        ridge = RidgeCV(alphas=np.logspace(-2, 4, 13)).fit(s0[train], mu[train])
        out[test] = mu[test] - ridge.predict(s0[test])
    explained = 1.0 - ((out - out.mean(0)) ** 2).sum() / ((mu - mu.mean(0)) ** 2).sum()
    return out, float(explained)


def run_game(ds, k: int, truth: np.ndarray, seed: int, over: dict) -> list[str]:
    import torch
    from sklearn.linear_model import LogisticRegression
    from sklearn.model_selection import cross_val_score

    from benchmarks.zoo.common import policy_mix_from
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import clustering_metrics
    from pcpg_dist.stages.clustering.latent_start import fit_latents, joined, kmeans_each
    from pcpg_dist.stages.clustering.policy_mix import _policy_view
    from pcpg_dist.stages.clustering.states import checked_sequences

    states, offsets = checked_sequences(ds)
    n = len(offsets) - 1
    cfg = ClusterConfig(method="policy_mix", k=k, **over)  # over: --set KEY=VALUE
    inputs = tuple(t.cpu() for t in _policy_view(ds, states, cfg)[3])

    def acc(labels) -> float:
        return clustering_metrics(truth, labels)["accuracy"]

    def em(start) -> float:
        return acc(policy_mix_from(ds, states, offsets, cfg, seed, start))

    with torch.random.fork_rng(devices=[]):
        mus = fit_latents(inputs, n, cfg, ds.n_actions, torch.Generator().manual_seed(seed))
    s0 = first_states(states, offsets)
    rests, explained = zip(*(residuals(mu, s0, seed) for mu in mus), strict=True)
    plain, resid = (kmeans_each(np.stack(m), k, cfg.kmeans_n_init, seed) for m in (mus, rests))
    lr = LogisticRegression(max_iter=2000)
    probe = [cross_val_score(lr, m, truth, cv=5).mean() for m in mus]
    probe_resid = [cross_val_score(lr, m, truth, cv=5).mean() for m in rests]
    start, start_resid = joined(plain, k, seed), joined(resid, k, seed)
    return [
        f"fits {len(mus)}, task R2 {np.mean(explained):+.2f}, probe {np.mean(probe):.3f} "
        f"(residuals {np.mean(probe_resid):.3f}); k-means each "
        f"{np.mean([acc(p) for p in plain]):.3f} (residuals {np.mean([acc(p) for p in resid]):.3f})"
        f", consensus {acc(start):.3f} ({acc(start_resid):.3f}), "
        f"EM from it {em(start):.3f} ({em(start_resid):.3f})"
    ]


def main() -> None:
    from benchmarks.zoo.check import for_design_games
    from benchmarks.zoo.common import overrides
    from pcpg_dist.common.devices import set_threads

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path, help="benchmarks.zoo.build --out")
    ap.add_argument("games", nargs="*")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    over = overrides(args.set)
    set_threads(1)
    warnings.filterwarnings("ignore", module="sklearn")
    for_design_games(
        args.root, args.games, ap.error, lambda *unit: run_game(*unit, args.seed, over)
    )


if __name__ == "__main__":
    main()
