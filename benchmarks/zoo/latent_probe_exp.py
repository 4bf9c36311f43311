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
    from sklearn.cluster import KMeans
    from sklearn.linear_model import LogisticRegression
    from sklearn.model_selection import cross_val_score

    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import clustering_metrics
    from pcpg_dist.stages.clustering.latent_start import consensus, fit_latents
    from pcpg_dist.stages.clustering.policy_mix import (
        LATENT_FIRST_ROUND,
        _fit_policy_mix,
        _policy_view,
    )
    from pcpg_dist.stages.clustering.states import checked_sequences

    states, offsets = checked_sequences(ds)
    n = len(offsets) - 1
    cfg = ClusterConfig(method="policy_mix", k=k, **over)  # over: --set KEY=VALUE
    inputs = tuple(t.cpu() for t in _policy_view(ds, states, cfg)[3])

    def acc(labels) -> float:
        return clustering_metrics(truth, labels)["accuracy"]

    def em(start) -> float:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            labels, *_ = _fit_policy_mix(
                ds, states, offsets, cfg, seed, {}, start=start,
                first_round_steps=LATENT_FIRST_ROUND * cfg.policy_steps,
            )  # fmt: skip
        return acc(labels)

    with torch.random.fork_rng(devices=[]):
        mus = fit_latents(inputs, n, cfg, ds.n_actions, torch.Generator().manual_seed(seed))
    s0 = first_states(states, offsets)
    plain, resid, explained, probe, probe_resid = [], [], [], [], []
    for r, mu in enumerate(mus):
        rest, share = residuals(mu, s0, seed)
        explained.append(share)
        plain.append(KMeans(k, n_init=10, random_state=seed + r).fit_predict(mu))
        resid.append(KMeans(k, n_init=10, random_state=seed + r).fit_predict(rest))
        lr = LogisticRegression(max_iter=2000)
        probe.append(cross_val_score(lr, mu, truth, cv=5).mean())
        probe_resid.append(cross_val_score(lr, rest, truth, cv=5).mean())
    joined = [consensus(np.stack(p), k, seed) if len(p) > 1 else p[0] for p in (plain, resid)]
    return [
        f"fits {len(mus)}, task R2 {np.mean(explained):+.2f}, probe {np.mean(probe):.3f} "
        f"(residuals {np.mean(probe_resid):.3f}); k-means each "
        f"{np.mean([acc(p) for p in plain]):.3f} (residuals {np.mean([acc(p) for p in resid]):.3f})"
        f", consensus {acc(joined[0]):.3f} ({acc(joined[1]):.3f}), "
        f"EM from it {em(joined[0]):.3f} ({em(joined[1]):.3f})"
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
