"""Experiment: contrastive trajectory embeddings of what a player does beyond the population.

    uv run python -m benchmarks.zoo.contrastive_exp ZOO_DIR [GAME ...] [--em]

The last untried idea of docs/zoo.md, "Why the gap remains": an embedding whose positives share
a style but not a task. Without labels the only sure positives are two parts of one trajectory,
and those share its task too; so the task is taken out of what the encoder sees. A population
policy pi_0(a | s) is fitted to every player; the encoder G maps a state to one feature vector
per action, and a step's feature is what its action adds beyond pi_0:

    phi_t = G(s_t)[a_t] - sum_a pi_0(a | s_t) G(s_t)[a]

A state's own part (anything G(s) says whatever the action) cancels, so which states an episode
visits (its task) can enter only through how this player acts there unlike the others.
A trajectory's embedding is the mean of its phi; two random halves of its steps are a positive
pair, the other trajectories negatives (InfoNCE, temperature ``TAU``). The learnt part over the
tenth session's fixed ``regions`` deviations (onehot(a) - pi_0 averaged within 8 state regions) is
that G learns which states, and which of their features, tell players apart.

Per game, Hungarian accuracy against the labels of k-means on the embeddings, with the
baseline (``contrastive``) and, to see what the baseline does, without it (``no baseline``:
phi_t = G(s_t)[a_t]); with ``--em``, policy_mix's EM started from the first. Design games only:
it refuses held-out games.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from sklearn.cluster import KMeans
from torch import nn

from benchmarks.zoo.check import read_unit
from benchmarks.zoo.common import design_games
from pcpg_dist.stages.clustering.policy_network import picked_log_probs

DIMS, HIDDEN, TAU = 16, 64, 0.1
POP_STEPS, STEPS, LR = 400, 300, 3e-3
BATCH_ROWS, BATCH_TRAJ = 8192, 256  # rows per step of pi_0; trajectories per InfoNCE step


def population_policy(s, a, valid, gen: torch.Generator) -> torch.Tensor:
    """(rows, n_actions) pi_0(. | s) of a small MLP fitted to every player's steps
    (``POP_STEPS`` Adam steps on ``BATCH_ROWS`` rows drawn each time)."""
    n_actions = valid.shape[1]
    torch.manual_seed(int(torch.randint(2**31, (1,), generator=gen)))
    net = nn.Sequential(
        nn.Linear(s.shape[1], HIDDEN), nn.Tanh(), nn.Linear(HIDDEN, HIDDEN), nn.Tanh(),
        nn.Linear(HIDDEN, n_actions),
    )  # fmt: skip
    opt = torch.optim.Adam(net.parameters(), lr=LR)
    for _ in range(POP_STEPS):
        rows = torch.randint(len(a), (min(len(a), BATCH_ROWS),), generator=gen)
        loss = -picked_log_probs(net(s[rows]), a[rows], valid[rows]).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        return torch.softmax(net(s).masked_fill(~valid, -1e9), 1)


class Encoder(nn.Module):
    """G(s): one DIMS-vector per action."""

    def __init__(self, state_dim: int, n_actions: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(state_dim, HIDDEN), nn.Tanh(), nn.Linear(HIDDEN, n_actions * DIMS)
        )
        self.n_actions = n_actions

    def step_features(self, s, a, pi0: torch.Tensor | None) -> torch.Tensor:
        g = self.net(s).view(len(s), self.n_actions, DIMS)
        picked = g[torch.arange(len(s)), a]
        return picked if pi0 is None else picked - (pi0[:, :, None] * g).sum(1)


def segment_mean(x: torch.Tensor, traj: torch.Tensor, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    total = torch.zeros(n, x.shape[1]).index_add_(0, traj, x)
    count = torch.zeros(n).index_add_(0, traj, torch.ones(len(traj)))
    return total / count.clamp(min=1)[:, None], count


def embed(inputs, n: int, pi0, seed: int) -> np.ndarray:
    """(n, DIMS) each trajectory's mean phi after STEPS InfoNCE steps on random halves."""
    s, a, valid, traj = inputs
    gen = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    enc = Encoder(s.shape[1], valid.shape[1])
    opt = torch.optim.Adam(enc.parameters(), lr=LR)
    for _ in range(STEPS):
        chosen = torch.randperm(n, generator=gen)[:BATCH_TRAJ]
        pick = torch.full((n,), -1, dtype=torch.long)
        pick[chosen] = torch.arange(len(chosen))
        rows = torch.nonzero(pick[traj] >= 0).squeeze(1)
        local = pick[traj[rows]]
        half = torch.randint(2, (len(rows),), generator=gen).bool()
        phi = enc.step_features(s[rows], a[rows], None if pi0 is None else pi0[rows])
        one, c1 = segment_mean(phi[half], local[half], len(chosen))
        two, c2 = segment_mean(phi[~half], local[~half], len(chosen))
        keep = (c1 > 0) & (c2 > 0)
        z1, z2 = F.normalize(one[keep], dim=1), F.normalize(two[keep], dim=1)
        logits = z1 @ z2.T / TAU
        target = torch.arange(len(z1))
        loss = 0.5 * (F.cross_entropy(logits, target) + F.cross_entropy(logits.T, target))
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        mean, _ = segment_mean(enc.step_features(s, a, pi0), traj, n)
    return F.normalize(mean, dim=1).double().numpy()


def run_game(ds, k: int, truth: np.ndarray, em: bool, seed: int) -> list[str]:
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import clustering_metrics
    from pcpg_dist.stages.clustering.policy_mix import _fit_policy_mix, _policy_view
    from pcpg_dist.stages.clustering.states import checked_sequences

    states, offsets = checked_sequences(ds)
    n = len(offsets) - 1
    cfg = ClusterConfig(method="policy_mix", k=k)
    inputs = _policy_view(ds, states, cfg)[3]
    t0 = time.perf_counter()
    pi0 = population_policy(*inputs[:3], torch.Generator().manual_seed(seed))
    out = []
    for name, base in (("contrastive", pi0), ("no baseline", None)):
        z = embed(inputs, n, base, seed)
        labels = KMeans(k, n_init=10, random_state=seed).fit_predict(z)
        acc = clustering_metrics(truth, labels)["accuracy"]
        line = f"{name} {acc:.3f}"
        if em and base is not None:
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(seed)
                final, *_ = _fit_policy_mix(ds, states, offsets, cfg, seed, {}, start=labels)
            line += f" -> em {clustering_metrics(truth, final)['accuracy']:.3f}"
        out.append(line)
    out.append(f"({time.perf_counter() - t0:.0f} s)")
    return out


def main() -> None:
    from pcpg_dist.common.devices import set_threads

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("zoo", type=Path, help="a folder from benchmarks.zoo.build")
    ap.add_argument("games", nargs="*")
    ap.add_argument("--em", action="store_true", help="also policy_mix's EM from the embedding")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    args = ap.parse_args()
    set_threads(1)
    for name in design_games(args.games, ap.error):
        game, _, ds = read_unit(name, args.zoo / name / "labelled")
        for seed in args.seeds:
            lines = run_game(ds, len(game.styles), np.asarray(ds.styles), args.em, seed)
            print(f"{name} seed {seed}: " + "; ".join(lines), flush=True)


if __name__ == "__main__":
    main()
