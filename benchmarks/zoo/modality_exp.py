"""Are a partition's clusters separate modes of the style latent, or cuts of a continuum?
(docs/zoo-notebook.md, "A consensus of latent fits on small logs".) Design games only.

    uv run python -m benchmarks.zoo.build --out zoo_data
    uv run python -m benchmarks.zoo.modality_exp zoo_data tictactoe highway [--runs 8 --steps 250]

For each cluster and its nearest cluster (by their centres in the latent), the latents of both
are projected on the line through the two centres and standardised; the modality is how much a
two-component Gaussian mixture beats one there (BIC difference per trajectory; near 0 or below:
one mode). A partition's modality is its weakest pair. Printed for the k-means partition of
each latent fit (the start ``policy_mix`` climbs from) and for the true styles; with ``--runs``
above 1, also for the consensus of the fits and for the fit a label-free choice by modality
would keep.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from sklearn.mixture import GaussianMixture


def pair_modality(mu: np.ndarray, labels: np.ndarray, a: int, b: int) -> float:
    """BIC(one Gaussian) - BIC(two), per point, of clusters a and b projected on their axis."""
    axis = mu[labels == a].mean(0) - mu[labels == b].mean(0)
    x = mu[(labels == a) | (labels == b)] @ (axis / max(np.linalg.norm(axis), 1e-12))
    if len(x) < 6:
        return 0.0
    x = ((x - x.mean()) / (x.std() + 1e-12))[:, None]
    one = GaussianMixture(1, random_state=0).fit(x).bic(x)
    two = GaussianMixture(2, random_state=0, n_init=3).fit(x).bic(x)
    return float((one - two) / len(x))


def modality(mu: np.ndarray, labels: np.ndarray, k: int) -> float:
    """The weakest pair: each non-empty cluster against its nearest cluster."""
    used = [c for c in range(k) if (labels == c).any()]
    centres = np.stack([mu[labels == c].mean(0) for c in used])
    out = []
    for i, a in enumerate(used):
        dist = np.linalg.norm(centres - centres[i], axis=1)
        dist[i] = np.inf
        out.append(pair_modality(mu, labels, a, used[int(np.argmin(dist))]))
    return min(out) if len(out) > 1 else 0.0


def run_game(ds, k: int, truth: np.ndarray, args) -> list[str]:
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import clustering_metrics
    from pcpg_dist.stages.clustering.latent_start import consensus, fit_latents, kmeans_each
    from pcpg_dist.stages.clustering.policy_mix import _policy_view
    from pcpg_dist.stages.clustering.states import checked_sequences

    states, offsets = checked_sequences(ds)
    n, out = len(offsets) - 1, []
    cfg = ClusterConfig(method="policy_mix", k=k, latent_runs=args.runs, latent_steps=args.steps)
    inputs = tuple(t.cpu() for t in _policy_view(ds, states, cfg)[3])

    def acc(labels) -> float:
        return clustering_metrics(truth, labels)["accuracy"]

    for seed in args.seeds:
        mus = fit_latents(inputs, n, cfg, ds.n_actions, torch.Generator().manual_seed(seed))
        parts = kmeans_each(mus, k, cfg.kmeans_n_init, seed)
        mods = [modality(m, p, k) for m, p in zip(mus, parts, strict=True)]
        truth_mod = np.mean([modality(m, truth, k) for m in mus])
        line = "fits " + " ".join(f"{acc(p):.3f}/{m:.2f}" for p, m in zip(parts, mods, strict=True))
        line += f"; true styles' modality {truth_mod:.2f}"
        if len(parts) > 1:
            joint = consensus(parts, k, seed)
            line += (
                f"; consensus {acc(joint):.3f}/{np.mean([modality(m, joint, k) for m in mus]):.2f}"
                f"; kept by modality {acc(parts[int(np.argmax(mods))]):.3f}"
            )
        out.append(f"seed {seed} (accuracy/modality): {line}")
    return out


def main() -> None:
    from benchmarks.zoo.check import for_design_games
    from pcpg_dist.common.devices import set_threads

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path, help="benchmarks.zoo.build --out")
    ap.add_argument("games", nargs="+")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--runs", type=int, default=1, help="latent fits side by side")
    ap.add_argument("--steps", type=int, default=500, help="Adam steps of each fit")
    args = ap.parse_args()
    set_threads(1)
    for_design_games(args.root, args.games, ap.error, lambda *unit: run_game(*unit, args))


if __name__ == "__main__":
    main()
