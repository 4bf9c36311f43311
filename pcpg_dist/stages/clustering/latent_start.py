"""policy_mix's default start: a continuous style latent per trajectory, learnt with one shared
policy, then k-means on the latents.

Each trajectory i has its own Gaussian posterior q(z_i) = N(mu_i, sigma_i^2) over a small latent
(``clustering.latent_dims``; no encoder: mu_i and sigma_i are parameters). One policy
pi(a | s, z) is fitted to every step by a beta-weighted evidence lower bound: the summed
log pi(a_t | s_t, z_i) with z_i drawn from q(z_i), minus ``latent_beta`` x KL(q(z_i) || N(0, I)).
The state is the policy's input, so a trajectory's latent pays only for what the state does not
already explain: how it acts where others act otherwise, not which task its episode set. That
is what policy_mix's hard EM, started from k-means on counters, missed on games with a new task
every episode: it settled in a partition by task (docs/zoo.md, "A style latent as policy_mix's
start"). The latent's fit is continuous and joint, with no hard assignment to get stuck in.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import torch
from sklearn.cluster import AgglomerativeClustering, KMeans
from sklearn.exceptions import ConvergenceWarning
from torch import nn

from pcpg_dist.stages.clustering.legal_actions import (
    Legal,
    as_legal,
    linear_at,
    on_legal_ids,
    pair_log_probs,
)
from pcpg_dist.stages.clustering.policy_network import Tanh, picked_log_probs, tanh, uniform_init

#: hidden units of the latent policy (as measured in benchmarks/zoo/latent_exp.py)
LATENT_HIDDEN = 64
#: rows per Adam step of the latent fit (a seeded draw with replacement; every row on smaller logs)
LATENT_ROWS = 4096
#: ``latent_runs: auto``: on a small log, this many fits share one fit's budget (each half the
#: steps, :data:`CONSENSUS_ROWS` rows a step) and are joined by their :func:`consensus`
CONSENSUS_RUNS = 8
CONSENSUS_ROWS = 1024
#: ... where each of them still draws every row of the log this many times on average
#: (``latent_steps`` / 2 x :data:`CONSENSUS_ROWS` / rows): one fit of 500 steps draws each of
#: mujoco_pendulum's 116,340 rows 17.6 times and finds its styles, fits drawing them 2-9 times
#: did not (docs/zoo-notebook.md, "A consensus of latent fits")
CONSENSUS_VISITS = 16


def latent_plan(cfg, rows: int) -> tuple[int, int, int]:
    """(fits, Adam steps each, rows a step) of the latent start on a log of ``rows`` rows.
    ``latent_runs: auto``: :data:`CONSENSUS_RUNS` fits of half ``latent_steps`` where each
    still draws every row :data:`CONSENSUS_VISITS` times (logs of up to 16,000 rows at the
    default 500 steps), one fit otherwise; a number: that many fits of ``latent_steps``."""
    if cfg.latent_runs != "auto":
        return cfg.latent_runs, cfg.latent_steps, LATENT_ROWS
    steps = max(1, cfg.latent_steps // 2)
    if steps * min(rows, CONSENSUS_ROWS) >= CONSENSUS_VISITS * rows:
        return CONSENSUS_RUNS, steps, CONSENSUS_ROWS
    return 1, cfg.latent_steps, LATENT_ROWS


class LatentPolicy(nn.Module):
    """pi(a | s, z) and each trajectory's posterior N(mu, sigma^2) over z. The logits are
    linear in [h, z] plus a bilinear term z^T M_a h (h: a tanh MLP of [s, z]): z picks which
    features of the state count, as when styles head for different targets. Without the bilinear
    term the latent alone was 0.57 on cartpole (0.99 with it) and, on a toy of four styles that
    each follow their own one of four goal directions, policy_mix from it ended at 0.48 (0.99)."""

    def __init__(self, state_dim: int, n: int, dims: int, hidden: int, n_actions: int) -> None:
        super().__init__()
        self.mu = nn.Parameter(torch.zeros(n, dims))
        self.log_sigma = nn.Parameter(torch.full((n, dims), -1.0))
        self.trunk = nn.Sequential(
            nn.Linear(state_dim + dims, hidden), Tanh(), nn.Linear(hidden, hidden), Tanh()
        )
        self.head = nn.Linear(hidden + dims, n_actions)
        self.bilinear = nn.Linear(hidden, n_actions * dims, bias=False)
        self.dims, self.n_actions = dims, n_actions

    def reset_parameters(self, gen: torch.Generator) -> None:
        """PyTorch's default init and mu ~ N(0, 0.01^2), drawn from a local generator."""
        with torch.no_grad():
            self.mu.copy_(0.01 * torch.randn(self.mu.shape, generator=gen))
        uniform_init((self.bilinear, self.trunk[0], self.trunk[2], self.head), gen)

    def step_nll(self, s, a, valid, traj, noise: torch.Tensor) -> torch.Tensor:
        """-log pi(a_t | s_t, z) of each row, z = mu + sigma x ``noise`` of the row's trajectory."""
        return self.nll_given(s, a, valid, self.mu[traj] + noise * self.log_sigma[traj].exp())

    def nll_given(self, s, a, valid, z: torch.Tensor) -> torch.Tensor:
        """-log pi(a_t | s_t, z_t) of each row for the row's own ``z``."""
        h = self.trunk(torch.cat([s, z], 1))
        valid = as_legal(valid, a)
        if isinstance(valid, Legal):  # the legal pairs only (legal_actions)
            bilinear = self.bilinear.weight.view(self.n_actions, self.dims, -1).transpose(0, 1)
            mod = linear_at(h, bilinear, None, valid) * z.T.index_select(1, valid.row)
            logits = linear_at(torch.cat([h, z], 1), self.head.weight, self.head.bias, valid)
            return -pair_log_probs(logits + mod.sum(0), valid)
        mod = self.bilinear(h).view(-1, self.n_actions, self.dims)  # z also scales the features
        logits = self.head(torch.cat([h, z], 1)) + (mod * z[:, None, :]).sum(-1)
        return -picked_log_probs(logits, a, valid)

    def kl(self) -> torch.Tensor:
        """KL(q(z_i) || N(0, I)) of every trajectory."""
        return 0.5 * (self.mu**2 + (2 * self.log_sigma).exp() - 2 * self.log_sigma - 1).sum(1)


class LatentPolicies(nn.Module):
    """``runs`` independent :class:`LatentPolicy` fits side by side (batched matrix products: one
    pass fits them all; ``clustering.latent_runs``), the same model as :class:`LatentPolicy`
    with each fit's weights stacked."""

    def __init__(
        self, state_dim: int, n: int, dims: int, hidden: int, n_actions: int, runs: int
    ) -> None:
        super().__init__()
        self.mu = nn.Parameter(torch.zeros(runs, n, dims))
        self.log_sigma = nn.Parameter(torch.full((runs, n, dims), -1.0))
        self.sizes = (state_dim + dims, hidden, hidden + dims, n_actions, dims, runs)
        shapes = {  # name: (fan in, shape of one fit's weight or bias)
            "w1": (state_dim + dims, (state_dim + dims, hidden)),
            "b1": (state_dim + dims, (1, hidden)),
            "w2": (hidden, (hidden, hidden)),
            "b2": (hidden, (1, hidden)),
            "wh": (hidden + dims, (hidden + dims, n_actions)),
            "bh": (hidden + dims, (1, n_actions)),
            "wb": (hidden, (hidden, n_actions * dims)),  # the bilinear term
        }
        self.fan_in = {name: fan for name, (fan, _) in shapes.items()}
        self.drawn = {name: (runs, *shape) for name, (_, shape) in shapes.items()}
        for name, shape in self.drawn.items():  # the stored shape, read off a storage-free view
            stored = self.by_action(name, torch.empty(shape, device="meta")).shape
            setattr(self, name, nn.Parameter(torch.empty(stored)))

    def by_action(self, name: str, drawn: torch.Tensor) -> torch.Tensor:
        """How a weight drawn in its layer's shape is stored: the head's and the bilinear term's
        action by action, (runs, actions, hidden + dims) and (runs, dims, actions, hidden), so
        the legal pairs read them in place (a copy of them each step took a fifth of chess's
        step); the other weights as drawn. The draws, and so every fit's numbers, are those of
        the layers' own shapes."""
        runs, hidden = drawn.shape[0], self.sizes[1]
        n_actions, dims = self.sizes[3], self.sizes[4]
        if name == "wh":
            return drawn.transpose(1, 2)
        if name == "wb":
            return drawn.view(runs, hidden, n_actions, dims).permute(0, 3, 2, 1)
        return drawn

    def as_drawn(self, name: str) -> torch.Tensor:
        """A weight in its layer's shape (contiguous: the dense path's matrix products run on
        the same layout, and so give the same numbers, as before it was stored by action)."""
        weight = getattr(self, name)
        if name == "wh":
            return weight.transpose(1, 2).contiguous()
        runs, dims, n_actions, hidden = weight.shape
        return weight.permute(0, 3, 2, 1).reshape(runs, hidden, n_actions * dims)

    def reset_parameters(self, gen: torch.Generator) -> None:
        """PyTorch's default init of every layer (uniform +-1/sqrt(fan in), each fit its own
        draw) and mu ~ N(0, 0.01^2), drawn from ``gen``."""
        with torch.no_grad():
            self.mu.copy_(0.01 * torch.randn(self.mu.shape, generator=gen))
            for name, fan in self.fan_in.items():
                bound = 1.0 / math.sqrt(fan)
                drawn = (torch.rand(self.drawn[name], generator=gen) * 2 - 1) * bound
                getattr(self, name).copy_(self.by_action(name, drawn))

    def step_nll(self, s, a, valid, traj, noise: torch.Tensor) -> torch.Tensor:
        """(rows, runs): -log pi(a_t | s_t, z) of each row under each fit, z = mu + sigma x
        ``noise`` (runs, rows, dims) of the row's trajectory."""
        *_, n_actions, dims, runs = self.sizes
        z = self.mu[:, traj] + noise * self.log_sigma[:, traj].exp()
        x = torch.cat([s.expand(runs, -1, -1), z], 2)
        h = tanh(torch.baddbmm(self.b1, x, self.w1))
        h = tanh(torch.baddbmm(self.b2, h, self.w2))
        valid = as_legal(valid, a)
        if isinstance(valid, Legal):  # the legal pairs only (legal_actions)
            mod = linear_at(h[:, None], self.wb, None, valid)  # (runs, dims, P)
            mod = (mod * z.transpose(1, 2).index_select(2, valid.row)).sum(1)
            logits = linear_at(torch.cat([h, z], 2), self.wh, self.bh[:, 0], valid) + mod
            return -pair_log_probs(logits, valid).T
        mod = torch.bmm(h, self.as_drawn("wb")).view(runs, len(a), n_actions, dims)
        logits = torch.baddbmm(self.bh, torch.cat([h, z], 2), self.as_drawn("wh"))
        logits = logits + (mod * z[:, :, None]).sum(-1)  # z also scales the features
        return -picked_log_probs(logits.transpose(0, 1), a, valid)

    def kl(self) -> torch.Tensor:
        """KL(q(z_i) || N(0, I)) summed over every trajectory and fit."""
        return 0.5 * (self.mu**2 + (2 * self.log_sigma).exp() - 2 * self.log_sigma - 1).sum()


def fit_latent_network(inputs, n: int, cfg, n_actions: int, gen: torch.Generator):
    """A :class:`LatentPolicy` (or, for several fits, :class:`LatentPolicies`) after the Adam
    steps of :func:`latent_plan` (``inputs``:
    :func:`.policy_network.policy_inputs`, on the CPU). Several fits use the same rows every step
    and differ by their initial weights and posterior draws; their losses are summed, and Adam's
    update of a parameter depends on its own gradient only, so each fit follows its own loss."""
    s, a, valid, traj = inputs
    total = len(a)
    runs, steps, rows_per_step = latent_plan(cfg, total)
    if runs == 1:
        net = LatentPolicy(s.shape[1], n, cfg.latent_dims, LATENT_HIDDEN, n_actions)
    else:
        net = LatentPolicies(s.shape[1], n, cfg.latent_dims, LATENT_HIDDEN, n_actions, runs)
    net.reset_parameters(gen)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.policy_lr)
    for _ in range(steps):
        if total > rows_per_step:
            rows = torch.randint(total, (rows_per_step,), generator=gen)
            batch, scale = (s[rows], a[rows], valid[rows], traj[rows]), total / rows_per_step
        else:
            batch, scale = inputs, 1.0
        # (rows, dims) for one fit, (runs, rows, dims) side by side: mu's leading dimensions
        noise = torch.randn((*net.mu.shape[:-2], len(batch[1]), cfg.latent_dims), generator=gen)
        nll = scale * net.step_nll(*batch, noise).sum()
        loss = (nll + cfg.latent_beta * net.kl().sum()) / total
        opt.zero_grad()
        loss.backward()
        opt.step()
    return net


def fit_latents(inputs, n: int, cfg, n_actions: int, gen: torch.Generator) -> np.ndarray:
    """(fits, n, latent_dims) float64: each fit's posterior mean of every trajectory
    (:func:`fit_latent_network`; the fits of :func:`latent_plan`)."""
    net = fit_latent_network(inputs, n, cfg, n_actions, gen)
    return net.mu.detach().double().numpy().reshape(-1, n, cfg.latent_dims)


#: trajectories the consensus links directly (average linkage needs their n x n co-association);
#: on a larger log the others join the cluster whose members share their clusters most often
CONSENSUS_LINKED = 2000


def consensus(parts: np.ndarray, k: int, seed: int) -> np.ndarray:
    """One partition from ``parts`` (runs, n): average linkage on the co-association (the share of
    the partitions in which two trajectories share a cluster). On a log of more than
    :data:`CONSENSUS_LINKED` trajectories a seeded sample of that many is linked, and every other
    trajectory joins the cluster with which it has the highest mean co-association."""
    runs, n = parts.shape
    onehot = (parts.T[:, :, None] == np.arange(k)).reshape(n, runs * k).astype(np.float32)
    linked = np.arange(n)
    if n > CONSENSUS_LINKED:
        linked = np.sort(np.random.default_rng(seed).choice(n, CONSENSUS_LINKED, replace=False))
    together = onehot[linked] @ onehot[linked].T / runs
    labels = AgglomerativeClustering(k, metric="precomputed", linkage="average").fit_predict(
        1.0 - together
    )
    if len(linked) == n:
        return labels.astype(np.int64)
    profile = np.stack([onehot[linked[labels == c]].mean(0) for c in range(k)])
    out = (onehot @ profile.T).argmax(1)
    out[linked] = labels
    return out.astype(np.int64)


def kmeans_each(mu: np.ndarray, k: int, n_init: int, seed: int) -> np.ndarray:
    """(fits, n): k-means (``n_init`` starts, seeded ``seed`` + the fit's index) on each fit's
    latents ``mu`` (fits, n, dims)."""
    with warnings.catch_warnings():  # identical latents (every trajectory alike): fewer centres
        warnings.simplefilter("ignore", ConvergenceWarning)
        return np.stack(
            [
                KMeans(n_clusters=k, n_init=n_init, random_state=seed + r).fit_predict(run)
                for r, run in enumerate(mu)
            ]
        )


def joined(parts: np.ndarray, k: int, seed: int) -> np.ndarray:
    """One partition of ``parts`` (fits, n): the only one, or their :func:`consensus`."""
    return parts[0] if len(parts) == 1 else consensus(parts, k, seed)


def latent_start(inputs, n: int, cfg, n_actions: int, seed: int) -> np.ndarray:
    """policy_mix's start: :func:`kmeans_each` of :func:`fit_latents`' fits
    (:func:`latent_plan`), :func:`joined`. One fit's partition moves with its seed on small logs
    (tictactoe 0.44-0.60 over eight seeds); with the consensus of eight, ``bag_auto`` rose on
    every seed of the five small design games of the zoo (docs/zoo-notebook.md, "A consensus of
    latent fits on small logs"). On a log of many action ids and few legal, the fits see the ids
    legal somewhere in it only (:func:`.legal_actions.on_legal_ids`)."""
    gen = torch.Generator().manual_seed(seed)
    s, a, valid, traj = (t.cpu() for t in inputs)
    a, valid, n_actions = on_legal_ids(a, valid, n_actions)
    mu = fit_latents((s, a, valid, traj), n, cfg, n_actions, gen)
    return joined(kmeans_each(mu, cfg.k, cfg.kmeans_n_init, seed), cfg.k, seed)
