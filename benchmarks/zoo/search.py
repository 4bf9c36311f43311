"""Is policy_mix's gap a limit of its search or of its objective? Measured per design game.

    uv run python -m benchmarks.zoo.search tictactoe highway leduc_poker      # full size
    uv run python -m benchmarks.zoo.search --ci tictactoe                     # a quick look

For each game, policy_mix's hard EM is run from four starts (the default k-means on counters;
the true styles; each with the first round trained ``--warmup`` times longer) and every final
partition is scored two ways that do not depend on how long EM happened to train: a fresh
network fitted to the partition for a fixed number of Adam steps, its mean log-likelihood a step
of each trajectory under its own cluster's policy, in-sample and on held-out trajectories
(2-fold). If EM started from the styles stays near them, and the styles score better than what
the default start reaches, the gap is the search's; if the default's partition scores better, it
is the objective's. Held-out games are refused: they take no part in design decisions.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from benchmarks.zoo.common import design_games, load_game


def partition_scores(
    ds, labels: np.ndarray, k: int, steps: int, seed: int = 0, rows: int = 0
) -> dict:
    """A fresh policy mixture fitted to ``labels`` for ``steps`` Adam steps: the mean
    log-likelihood a step of each trajectory's actions under its own cluster's policy, in-sample
    (``fit``) and on trajectories left out of the fit (``held_out``, 2-fold). ``rows``: fit each
    network to a seeded sample of at most that many of its steps (0: every step); every step is
    still scored."""
    from pcpg_dist.stages.clustering.policy_network import PolicyMixture, policy_inputs
    from pcpg_dist.stages.clustering.states import checked_sequences, fit_normaliser

    states, offsets = checked_sequences(ds)
    n = len(offsets) - 1
    mean, std = fit_normaliser(states)
    s, a, valid, traj = policy_inputs(ds, states, mean, std)
    own = torch.from_numpy(np.asarray(labels, np.int64))[traj]
    fold = torch.from_numpy(np.random.default_rng(seed).integers(0, 2, n))[traj]
    out = {"held_out": 0.0}
    for part in ("fit", 0, 1):
        mask = torch.ones(len(a), dtype=torch.bool) if part == "fit" else fold == part
        gen = torch.Generator().manual_seed(seed)
        fit = torch.nonzero(mask).flatten()
        if rows and len(fit) > rows:
            fit = fit[torch.randperm(len(fit), generator=gen)[:rows]]
        policy = PolicyMixture(states.shape[1], 32, k, int(ds.n_actions))
        policy.reset_parameters(gen)
        opt = torch.optim.Adam(policy.parameters(), lr=0.01)
        fs, fa, fvalid, fown = s[fit], a[fit], valid[fit], own[fit][None]  # once, not every step
        for _ in range(steps):
            lp = policy.step_log_probs(fs, fa, fvalid)
            loss = -lp.gather(0, fown).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        with torch.no_grad():
            lp = policy.step_log_probs(s, a, valid).gather(0, own[None])[0]
        if part == "fit":
            out["fit"] = float(lp.mean())
        else:
            out["held_out"] += float(lp[~mask].sum()) / len(a)
    return out


def search_game(name: str, ci: bool, warmup: int, steps: int) -> list[dict]:
    from benchmarks.zoo.check import labelled_dataset
    from pcpg_dist.common.devices import set_threads
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import clustering_metrics
    from pcpg_dist.stages.clustering.policy_mix import _fit_policy_mix
    from pcpg_dist.stages.clustering.states import checked_sequences

    set_threads(1)
    game = load_game(name)
    ds = labelled_dataset(name, ci)
    k = len(game.styles)
    cfg = ClusterConfig(method="policy_mix", k=k)
    states, offsets = checked_sequences(ds)
    truth = np.asarray(ds.styles, np.int64)
    rows = []
    for start_name, start in (("k-means on counters", None), ("true styles", truth)):
        for first in (None, warmup * cfg.policy_steps):
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(0)
                labels, *_ = _fit_policy_mix(
                    ds, states, offsets, cfg, 0, {}, start=start, first_round_steps=first
                )
            acc = float(clustering_metrics(truth, labels)["accuracy"])
            rows.append(
                {
                    "game": name,
                    "start": start_name,
                    "first_round_steps": first or cfg.policy_steps,
                    "accuracy": acc,
                    **partition_scores(ds, labels, k, steps),
                }
            )
    rows.append({"game": name, "start": "(the styles themselves)", "accuracy": 1.0,
                 **partition_scores(ds, truth, k, steps)})  # fmt: skip
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("games", nargs="*", help="design games (default: every design game)")
    parser.add_argument("--ci", action="store_true", help="the CI-size logs")
    parser.add_argument("--warmup", type=int, default=4, help="first-round training multiple")
    parser.add_argument("--steps", type=int, default=400, help="Adam steps of the scoring fit")
    args = parser.parse_args()
    games = design_games(args.games, parser.error)
    print("| game | start | first round steps | accuracy | fit ll/step | held-out ll/step |")
    print("|---|---|---|---|---|---|")
    for g in games:
        for r in search_game(g, args.ci, args.warmup, args.steps):
            print(
                f"| {r['game']} | {r['start']} | {r.get('first_round_steps', '')} | "
                f"{r['accuracy']:.3f} | {r['fit']:.4f} | {r['held_out']:.4f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
