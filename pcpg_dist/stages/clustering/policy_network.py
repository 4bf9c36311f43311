"""The network of ``policy_mix``: k policies over one shared trunk, and the steps it scores.

A trajectory's score for cluster c is its log prior plus the summed log-likelihood of its actions
under policy c; the saved model (:mod:`.model`) and the fit (:mod:`.policy_mix`) both use it.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from pcpg_dist.common.errors import DataError
from pcpg_dist.stages.clustering.legal_actions import Legal, as_legal, linear_at, pair_log_probs


def uniform_init(linears, generator: torch.Generator) -> None:
    """PyTorch's default init of each ``nn.Linear`` in turn (weight, then bias where it has one:
    uniform +-1/sqrt(in_features)), drawn from ``generator`` instead of the global RNG."""
    with torch.no_grad():
        for lin in linears:
            bound = 1.0 / math.sqrt(lin.in_features)
            lin.weight.uniform_(-bound, bound, generator=generator)
            if lin.bias is not None:
                lin.bias.uniform_(-bound, bound, generator=generator)


#: exp's floor under a mask (:func:`masked_exp`): torch's CPU exp of an argument below about
#: -87.3 (a result under float32's smallest normal number, or 0) took 20-150x the time of one
#: above it on the builds measured here, and most entries of a masked row are -1e9
EXP_FLOOR = -87.0


def picked_log_probs(logits: torch.Tensor, actions: torch.Tensor, valid: torch.Tensor):
    """log softmax(logits)[a] of each row's taken action, the actions not ``valid`` masked out.

    ``logits``: (rows, n_actions) or (rows, k, n_actions); ``actions``: (rows,); ``valid``: (rows,
    n_actions) bool. Returns (rows,) or (rows, k). Computed as picked - max - log sum exp(logits -
    max) over a row-wise additive mask: forward and backward on the CPU 1.6-2.1x faster than a
    masked_fill, log_softmax and gather with 3-9 actions, within 10 % of it with 18
    (``benchmarks/bench_log_probs.py``); policy_mix spent a third of its time in log_softmax.
    """
    shape = (len(actions),) + (1,) * (logits.dim() - 2)
    row_valid = None if bool(valid.all()) else valid.view(*shape, -1)  # all valid: no mask
    if row_valid is not None:
        mask = torch.zeros(row_valid.shape, device=logits.device).masked_fill_(~row_valid, -1e9)
        logits = logits + mask
    top = logits.detach().amax(-1, keepdim=True)
    picked = logits.gather(-1, actions.view(*shape, 1).expand(*logits.shape[:-1], 1))
    terms = (logits - top).exp() if row_valid is None else masked_exp(logits - top, row_valid)
    return (picked - top - terms.sum(-1, keepdim=True).log()).squeeze(-1)


def masked_exp(shifted: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """exp(``shifted``) where ``valid``, exactly 0 elsewhere (as exp(-1e9) is), without calling
    exp below :data:`EXP_FLOOR` or letting a term under float32's smallest normal number into
    the backward pass: both ran 20-150x slower per element (``benchmarks/bench_log_probs.py``)."""
    return shifted.clamp(min=EXP_FLOOR).exp() * valid


class _SigmoidTanh(torch.autograd.Function):
    """tanh(x) as 2 sigmoid(2x) - 1 (within 2e-7 of torch.tanh), its gradient from the output."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        y = torch.sigmoid(2.0 * x).mul_(2.0).sub_(1.0)
        ctx.save_for_backward(y)
        return y

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (y,) = ctx.saved_tensors
        return torch.ops.aten.tanh_backward(grad, y)


def tanh(x: torch.Tensor) -> torch.Tensor:
    """The clusterers' tanh: torch.tanh is a scalar call per element on the CPU builds measured
    here, 3-6x slower than sigmoid, and took a fifth of a policy_mix fit
    (``benchmarks/bench_tanh.py``); 2 sigmoid(2x) - 1 vectorises."""
    return _SigmoidTanh.apply(x)


class Tanh(nn.Module):
    """:func:`tanh` as a layer (no parameters: a drop-in for ``nn.Tanh`` in saved models)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return tanh(x)


class PolicyMixture(nn.Module):
    """k policies pi_c(a | s) over one shared tanh MLP trunk: k softmax heads of n_actions logits.

    ``policy_mix`` clusters with it: a trajectory's score for cluster c is log prior_c plus the sum
    of log pi_c(a_t | s_t) over its steps (the transitions are the same for every style, so they
    cancel). The states are normalised with the training mean/std before the trunk.
    """

    def __init__(
        self, state_dim: int, hidden_size: int, k: int, n_actions: int, time: bool = False
    ) -> None:
        super().__init__()
        self.k, self.n_actions, self.time = int(k), int(n_actions), bool(time)
        self.trunk = nn.Sequential(
            nn.Linear(state_dim + self.time, hidden_size),
            Tanh(),
            nn.Linear(hidden_size, hidden_size),
            Tanh(),
        )
        self.heads = nn.Linear(hidden_size, self.k * self.n_actions)
        self.register_buffer("log_prior", torch.full((self.k,), -math.log(self.k)))

    def reset_parameters(self, generator: torch.Generator) -> None:
        """PyTorch's default init, drawn from a local generator (see SequenceAutoencoder)."""
        uniform_init((self.trunk[0], self.trunk[2], self.heads), generator)

    def step_log_probs(
        self, states: torch.Tensor, actions: torch.Tensor, valid: torch.Tensor | Legal
    ) -> torch.Tensor:
        """(k, rows): log pi_c(a_t | s_t) of every step under every head, invalid actions masked
        (``valid`` (rows, n_actions) bool, or :class:`.legal_actions.Legal` pairs)."""
        h = self.trunk(states)
        if isinstance(valid, Legal):
            weight = self.heads.weight.view(self.k, self.n_actions, -1)
            bias = self.heads.bias.view(self.k, self.n_actions)
            return pair_log_probs(linear_at(h, weight, bias, valid), valid)
        logits = self.heads(h).view(len(states), self.k, self.n_actions)
        return picked_log_probs(logits, actions, valid).T


def policy_states(dataset, states: np.ndarray, time: bool) -> np.ndarray:
    """The states a policy sees, one row per step: ``states``, with ``time`` (``clustering.
    policy_time``) and a last column log(1 + t) for the step's index t in its trajectory, so a
    policy may act by schedule. The normaliser is fitted to these columns."""
    if not time:
        return states
    return np.hstack([states, np.log1p(dataset.row_step).astype(states.dtype)[:, None]])


def policy_inputs(dataset, seen: np.ndarray, mean: np.ndarray, std: np.ndarray):
    """The steps a policy mixture scores: the states it sees (:func:`policy_states`) normalised,
    actions, valid masks, trajectory index.

    Only rows with an action (every row but a trajectory's last); a taken action always counts as
    valid, so a log whose valid mask disagrees with its actions cannot give -inf scores.
    """
    actions = np.asarray(dataset.actions, np.int64)
    n_actions = int(dataset.n_actions)
    rows = np.flatnonzero(actions >= 0)
    if rows.size and actions[rows].max() >= n_actions:
        raise DataError(
            f"{dataset.domain}-{dataset.env}: action {int(actions[rows].max())} "
            f"outside 0..{n_actions - 1}"
        )
    valid = np.asarray(dataset.valid, bool)[rows].copy()
    valid[np.arange(rows.size), actions[rows]] = True
    traj = dataset.row_trajectory[rows]
    norm = ((seen[rows] - mean) / std).astype(np.float32)
    return (
        torch.from_numpy(norm),
        torch.from_numpy(actions[rows]),
        torch.from_numpy(valid),
        torch.from_numpy(traj),
    )


def trajectory_scores(policy: PolicyMixture, inputs, n: int) -> torch.Tensor:
    """(k, n): log prior + summed step log-likelihood of each trajectory under each policy."""
    s, a, valid, traj = inputs
    lp = policy.step_log_probs(s, a, as_legal(valid, a))
    return (
        torch.zeros(policy.k, n, device=lp.device).index_add_(1, traj, lp)
        + policy.log_prior[:, None]
    )


def posteriors(scores: torch.Tensor) -> np.ndarray:
    """(n, k) float32: each trajectory's posterior over the k policies, from
    :func:`trajectory_scores`' (k, n) scores (the reported latents of ``policy_mix``)."""
    return torch.softmax(scores, 0).T.numpy().astype(np.float32)
