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

import warnings

import numpy as np
import torch
from sklearn.cluster import KMeans
from sklearn.exceptions import ConvergenceWarning
from torch import nn

from pcpg_dist.stages.clustering.policy_network import picked_log_probs, uniform_init

#: hidden units of the latent policy (as measured in benchmarks/zoo/latent_exp.py)
LATENT_HIDDEN = 64
#: rows per Adam step of the latent fit (a seeded draw with replacement; every row on smaller logs)
LATENT_ROWS = 4096


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
            nn.Linear(state_dim + dims, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh()
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
        z = self.mu[traj] + noise * self.log_sigma[traj].exp()
        h = self.trunk(torch.cat([s, z], 1))
        mod = self.bilinear(h).view(-1, self.n_actions, self.dims)  # z also scales the features
        logits = self.head(torch.cat([h, z], 1)) + (mod * z[:, None, :]).sum(-1)
        return -picked_log_probs(logits, a, valid)

    def kl(self) -> torch.Tensor:
        """KL(q(z_i) || N(0, I)) of every trajectory."""
        return 0.5 * (self.mu**2 + (2 * self.log_sigma).exp() - 2 * self.log_sigma - 1).sum(1)


def fit_latents(inputs, n: int, cfg, n_actions: int, gen: torch.Generator) -> np.ndarray:
    """(n, latent_dims) float64: each trajectory's posterior mean after ``latent_steps`` Adam
    steps on :data:`LATENT_ROWS` rows each (``inputs``: :func:`.policy_network.policy_inputs`,
    on the CPU)."""
    s, a, valid, traj = inputs
    net = LatentPolicy(s.shape[1], n, cfg.latent_dims, LATENT_HIDDEN, n_actions)
    net.reset_parameters(gen)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.policy_lr)
    total = len(a)
    for _ in range(cfg.latent_steps):
        if total > LATENT_ROWS:
            rows = torch.randint(total, (LATENT_ROWS,), generator=gen)
            batch, scale = (s[rows], a[rows], valid[rows], traj[rows]), total / LATENT_ROWS
        else:
            batch, scale = inputs, 1.0
        noise = torch.randn((len(batch[1]), cfg.latent_dims), generator=gen)
        nll = scale * net.step_nll(*batch, noise).sum()
        loss = (nll + cfg.latent_beta * net.kl().sum()) / total
        opt.zero_grad()
        loss.backward()
        opt.step()
    return net.mu.detach().double().numpy()


def latent_start(inputs, n: int, cfg, n_actions: int, seed: int) -> np.ndarray:
    """policy_mix's start: k-means (``kmeans_n_init`` starts) on :func:`fit_latents`' means."""
    gen = torch.Generator().manual_seed(seed)
    mu = fit_latents(tuple(t.cpu() for t in inputs), n, cfg, n_actions, gen)
    with warnings.catch_warnings():  # identical latents (every trajectory alike): fewer centres
        warnings.simplefilter("ignore", ConvergenceWarning)
        kmeans = KMeans(n_clusters=cfg.k, n_init=cfg.kmeans_n_init, random_state=seed)
        return kmeans.fit_predict(mu)
