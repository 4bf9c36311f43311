"""EM over k style prototypes inside the latent start's own policy, measured on design games
(docs/zoo-notebook.md). Held-out games are refused.

    uv run python -m benchmarks.zoo.build --out zoo_data
    uv run python -m benchmarks.zoo.proto_exp zoo_data highway tictactoe

policy_mix's default start fits one policy pi(a | s, z) with a latent z per trajectory, takes
k-means on the latents, then runs EM over k separate heads. Here the k-means centres become k
prototypes z_c of that same policy, and hard EM runs in it: every trajectory moves to the
prototype under which its actions are most likely, then the policy and the prototypes are refitted
to the moved labels. The cluster identity then changes the policy's features (z enters the trunk
and scales its features), not only a linear head. For each game: k-means on the latents alone,
the prototype EM alone, policy_mix's EM from each (the first is today's default path).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch


def proto_em(net, inputs, n, k, start, gen, rounds: int, steps: int, min_share: float):
    """Hard EM over k prototypes of ``net`` from the labels ``start``; returns the labels."""
    from pcpg_dist.stages.clustering import latent_start as L
    from pcpg_dist.stages.clustering.policy_mix import reseed_small

    s, a, valid, traj = inputs
    labels = np.array(start, np.int64)
    mu = net.mu.detach()
    protos = torch.nn.Parameter(
        torch.stack([mu[torch.from_numpy(labels == c)].mean(0) for c in range(k)])
    )
    params = [p for name, p in net.named_parameters() if name not in ("mu", "log_sigma")]
    opt = torch.optim.Adam([*params, protos], lr=1e-3)
    total, n_steps = len(a), np.bincount(traj.numpy(), minlength=n).astype(np.float64)
    for r in range(rounds):
        own = torch.from_numpy(labels)
        for _ in range(steps if r else 4 * steps):
            rows = torch.randint(total, (min(total, L.LATENT_ROWS),), generator=gen)
            z = protos[own[traj[rows]]]
            loss = net.nll_given(s[rows], a[rows], valid[rows], z).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        with torch.no_grad():
            scores = torch.zeros(k, n, dtype=torch.float64)
            for c in range(k):
                nll = net.nll_given(s, a, valid, protos[c].expand(total, -1))
                scores[c].index_add_(0, traj, -nll.double())
        share = np.maximum(np.bincount(labels, minlength=k) / n, 1e-12)
        sc = scores.numpy() + np.log(share)[:, None]
        new = sc.argmax(0).astype(np.int64)
        reseeded = reseed_small(new, sc, n_steps, k, min_share)
        moved = float((new != labels).mean())
        labels = new
        if moved < 0.01 and not reseeded:
            break
    return labels


def run_game(ds, k, truth, args) -> list[str]:
    from sklearn.cluster import KMeans

    from benchmarks.zoo.common import policy_mix_from
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import clustering_metrics
    from pcpg_dist.stages.clustering.latent_start import fit_latent_network
    from pcpg_dist.stages.clustering.policy_mix import _policy_view
    from pcpg_dist.stages.clustering.states import checked_sequences

    states, offsets = checked_sequences(ds)
    n = len(offsets) - 1
    # one latent fit of latent_steps, as when these figures were measured (latent_runs auto
    # would fit eight on these small logs)
    cfg = ClusterConfig(method="policy_mix", k=k, policy_time=args.time_step, latent_runs=1)
    inputs = tuple(t.cpu() for t in _policy_view(ds, states, cfg)[3])

    def acc(labels) -> str:
        return f"{clustering_metrics(truth, labels)['accuracy']:.3f}"

    def em(start) -> str:
        return acc(policy_mix_from(ds, states, offsets, cfg, args.seed, start))

    if args.consensus:
        return [consensus(inputs, n, cfg, ds.n_actions, k, args, acc, em)]
    with torch.random.fork_rng(devices=[]):
        t0 = time.perf_counter()
        gen = torch.Generator().manual_seed(args.seed)
        net = fit_latent_network(inputs, n, cfg, ds.n_actions, gen)
        if args.readouts:
            return [readouts(net, k, args.seed, acc)]
        km = KMeans(n_clusters=k, n_init=cfg.kmeans_n_init, random_state=args.seed)
        start = km.fit_predict(net.mu.detach().double().numpy())
        t1 = time.perf_counter()
        protos = proto_em(
            net, inputs, n, k, start, gen, args.rounds, args.steps, cfg.policy_min_share
        )
        t2 = time.perf_counter()
    return [
        f"latent {acc(start)} -> em {em(start)} | proto {acc(protos)} -> em {em(protos)}"
        f" (latent {t1 - t0:.0f} s, proto {t2 - t1:.0f} s)"
    ]


def consensus(inputs, n, cfg, n_actions, k, args, acc, em) -> str:
    """k-means on the latents of ``args.consensus`` separate seeds, and the consensus
    (:func:`~pcpg_dist.stages.clustering.latent_start.consensus`) of the first 2, 4, ... of
    those partitions, alone and as policy_mix's start."""
    from sklearn.cluster import KMeans

    from pcpg_dist.stages.clustering.latent_start import consensus as joined
    from pcpg_dist.stages.clustering.latent_start import fit_latents

    parts, t0 = [], time.perf_counter()
    for seed in range(args.seed, args.seed + args.consensus):
        with torch.random.fork_rng(devices=[]):
            mu = fit_latents(inputs, n, cfg, n_actions, torch.Generator().manual_seed(seed))[0]
        parts.append(KMeans(k, n_init=10, random_state=seed).fit_predict(mu))
    each = (time.perf_counter() - t0) / args.consensus
    singles = [float(acc(p)) for p in parts]
    line = f"seeds {' '.join(f'{a:.3f}' for a in singles)} (mean {np.mean(singles):.3f}, {each:.1f} s each)"
    m = 2
    while m <= args.consensus:
        avg = joined(np.stack(parts[:m]), k, args.seed)
        line += f" | {m}: {acc(avg)} -> em {em(avg)}"
        m *= 2
    return line


def readouts(net, k: int, seed: int, acc) -> str:
    """Other partitions of the same latents: k-means weighted by each posterior's precision, a
    full-covariance Gaussian mixture, Ward linkage, and k-means on the means scaled by their
    posterior's standard deviation (a z-score of each coordinate)."""
    from sklearn.cluster import AgglomerativeClustering, KMeans
    from sklearn.mixture import GaussianMixture

    mu = net.mu.detach().double().numpy()
    var = (2 * net.log_sigma.detach().double()).exp().numpy()
    w = 1.0 / var.mean(1)
    parts = {
        "kmeans": KMeans(k, n_init=10, random_state=seed).fit_predict(mu),
        "weighted": KMeans(k, n_init=10, random_state=seed).fit_predict(mu, sample_weight=w),
        "gmm": GaussianMixture(k, n_init=5, random_state=seed).fit(mu).predict(mu),
        "ward": AgglomerativeClustering(k).fit_predict(mu),
        "snr": KMeans(k, n_init=10, random_state=seed).fit_predict(mu / np.sqrt(var)),
    }
    return " ".join(f"{name} {acc(p)}" for name, p in parts.items())


def main() -> None:
    from benchmarks.zoo.check import for_design_games
    from pcpg_dist.common.devices import set_threads

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path, help="benchmarks.zoo.build --out")
    ap.add_argument("games", nargs="*")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--steps", type=int, default=50, help="Adam steps a round (4x the first)")
    ap.add_argument("--consensus", type=int, default=0, help="seeds of a consensus")
    ap.add_argument("--readouts", action="store_true", help="other partitions of the latents")
    ap.add_argument("--time-step", action="store_true", help="policies see log(1 + t)")
    args = ap.parse_args()
    set_threads(1)
    for_design_games(args.root, args.games, ap.error, lambda *unit: run_game(*unit, args))


if __name__ == "__main__":
    main()
