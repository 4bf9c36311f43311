"""Log-likelihoods of the taken actions where a step allows a few of many actions.

A board or card game may have thousands of action ids of which a position allows a few dozen
(chess in PettingZoo's encoding: 4,672 ids, 20-40 legal). The policies' dense softmax computes
every id's logit for every row and every head, almost all of them masked out; here only the
legal (row, action) pairs are computed and normalised. The same log-probabilities (to float
rounding; ``tests/stages/test_legal_actions.py``), 10-60x faster a step on chess's shapes
(``benchmarks/bench_legal_actions.py``). Used where :func:`sparse_pays` says so: many actions,
few of them legal on the average row (:mod:`pcpg_dist.stages.legal_share`), on the CPU.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np
import torch

from pcpg_dist.stages.legal_share import few_legal


class Legal(NamedTuple):
    """The legal (row, action) pairs of some rows, row by row, each row's taken pair, and the
    pairs grouped by action (for the gradient of the actions' weights)."""

    row: torch.Tensor  # (P,) ascending
    action: torch.Tensor  # (P,)
    picked: torch.Tensor  # (rows,): index into the pairs of each row's taken action
    row_start: np.ndarray  # (rows + 1,): row r's pairs are row_start[r]:row_start[r + 1]
    by_action: np.ndarray  # (P,): the pairs ordered by action (stably)
    action_start: np.ndarray  # (n_actions + 1,): action a's run of by_action


def sparse_pays(valid: torch.Tensor) -> bool:
    """Whether ``valid`` (rows, n_actions) is worth :class:`Legal` pairs (module doc). On the
    CPU only: the pairs' kernel is numba's; a GPU keeps the dense softmax."""
    if valid.device.type != "cpu" or valid.ndim != 2:
        return False
    return few_legal(valid.shape[1], int(valid.sum()), valid.shape[0])


def legal_pairs(valid: torch.Tensor, actions: torch.Tensor) -> Legal:
    """The pairs of ``valid`` (rows, n_actions) bool; each row's taken ``actions`` must be legal
    (:func:`.policy_network.policy_inputs` makes them so)."""
    row, action = valid.nonzero(as_tuple=True)
    rows, n_actions = valid.shape
    key = row * n_actions + action  # ascending: nonzero walks row by row
    wanted = torch.arange(rows, device=valid.device) * n_actions + actions
    row_np, action_np = row.numpy(), action.numpy()  # on the CPU (sparse_pays)
    row_start = np.searchsorted(row_np, np.arange(rows + 1))
    by_action = np.argsort(action_np, kind="stable")
    action_start = np.searchsorted(action_np[by_action], np.arange(n_actions + 1))
    return Legal(row, action, torch.searchsorted(key, wanted), row_start, by_action, action_start)


def as_legal(valid: torch.Tensor | Legal, actions: torch.Tensor) -> torch.Tensor | Legal:
    """``valid`` as :class:`Legal` pairs where :func:`sparse_pays`, else as it is (pairs too)."""
    if isinstance(valid, Legal) or not sparse_pays(valid):
        return valid
    return legal_pairs(valid, actions)


def on_legal_ids(
    actions: torch.Tensor, valid: torch.Tensor, n_actions: int
) -> tuple[torch.Tensor, torch.Tensor, int]:
    """(actions, valid, n_actions) renumbered over the ids legal somewhere in ``valid`` (or
    taken), where :func:`sparse_pays`; as they are otherwise. An id never legal in the log is
    never scored at the legal pairs, so its weights only cost memory and Adam's time: chess's
    80-game log allows 1,745 of its 4,672 ids. Used by the latent start, whose networks live for
    one fit; the saved policies keep the log's own ids."""
    if not sparse_pays(valid):
        return actions, valid, n_actions
    used = valid.any(0)
    used[actions] = True
    new_id = torch.cumsum(used, 0) - 1
    return new_id[actions], valid[:, used], int(used.sum())


def pair_log_probs(logits: torch.Tensor, legal: Legal) -> torch.Tensor:
    """(..., rows): log softmax over each row's legal actions of the taken one, from the pairs'
    ``logits`` (..., P)."""
    lead, rows = logits.shape[:-1], len(legal.picked)
    row = legal.row.expand(*lead, -1)
    top = torch.full((*lead, rows), -torch.inf, device=logits.device)
    top = top.scatter_reduce(-1, row, logits.detach(), "amax")
    shifted = (logits - top.gather(-1, row)).exp()
    total = torch.zeros((*lead, rows), device=logits.device).scatter_add(-1, row, shifted)
    return logits.index_select(-1, legal.picked) - top - total.log()


def linear_at(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None, legal: Legal):
    """(..., P): a linear layer's outputs at the legal pairs only.

    ``weight`` (..., n_actions, in) and ``bias`` (..., n_actions) or None: G = prod(...) layers
    (heads, fits); ``x`` (rows, in), or (Gx, [1,] rows, in) where each of Gx inputs feeds G / Gx
    consecutive layers. Output ``a`` of row ``r`` is x[r] . weight[a] + bias[a], for each pair
    (r, a). The pairs' weights are never gathered: a fused kernel reads them in place, and its
    gradient sums each action's pairs (:class:`_PairLinear`)."""
    lead = weight.shape[:-2]
    n_actions, width = weight.shape[-2:]
    w = weight.reshape(-1, n_actions, width)
    b = None if bias is None else bias.reshape(len(w), n_actions)
    out = _PairLinear.apply(x.reshape(-1, x.shape[-2], width), w, b, legal)
    return out.view(*lead, -1)


class _PairLinear(torch.autograd.Function):
    """out[g, p] = x[g // (G / Gx), row_p] . weight[g, action_p] + bias[g, action_p] on the CPU
    (numba; every output and gradient cell summed in a fixed order: the same numbers whatever
    the thread count)."""

    @staticmethod
    def forward(ctx, x, weight, bias, legal: Legal):
        xs, ws = _np(x), _np(weight)
        bs = np.zeros(ws.shape[:2], np.float32) if bias is None else _np(bias)
        out = np.empty((len(ws), len(legal.row)), np.float32)
        _forward(xs, ws, bs, legal.row.numpy(), legal.action.numpy(), out)
        ctx.arrays, ctx.legal, ctx.has_bias = (xs, ws), legal, bias is not None
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, grad):
        (xs, ws), legal = ctx.arrays, ctx.legal  # contiguous copies made once, in forward
        g = _np(grad)
        gx = np.zeros_like(xs)
        gw, gb = np.zeros_like(ws), np.zeros(ws.shape[:2], np.float32)
        row, action = legal.row.numpy(), legal.action.numpy()
        _grad_x(g, ws, legal.row_start, action, gx)
        _grad_w(g, xs, row, legal.by_action, legal.action_start, gw, gb)
        gb_out = torch.from_numpy(gb) if ctx.has_bias else None
        return torch.from_numpy(gx), torch.from_numpy(gw), gb_out, None


#: reassociated sums vectorise (4x here); each cell is still summed in one fixed order
FAST = {"reassoc", "contract"}


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy()


@numba.njit(parallel=True, cache=True, fastmath=FAST)
def _forward(x, weight, bias, row, action, out):  # pragma: no cover - compiled
    groups, pairs = out.shape
    per, width = groups // x.shape[0], x.shape[2]
    for p in numba.prange(pairs):
        r, a = row[p], action[p]
        for g in range(groups):
            acc = bias[g, a]
            xg, wg = x[g // per, r], weight[g, a]
            for i in range(width):
                acc += xg[i] * wg[i]
            out[g, p] = acc


@numba.njit(parallel=True, cache=True, fastmath=FAST)
def _grad_x(grad, weight, row_start, action, gx):  # pragma: no cover - compiled
    groups = grad.shape[0]
    per, width = groups // gx.shape[0], gx.shape[2]
    for r in numba.prange(gx.shape[1]):
        for p in range(row_start[r], row_start[r + 1]):
            a = action[p]
            for g in range(groups):
                gg, wg, out = grad[g, p], weight[g, a], gx[g // per, r]
                for i in range(width):
                    out[i] += gg * wg[i]


@numba.njit(parallel=True, cache=True, fastmath=FAST)
def _grad_w(grad, x, row, by_action, action_start, gw, gb):  # pragma: no cover - compiled
    groups, n_actions, width = gw.shape
    per = groups // x.shape[0]
    for a in numba.prange(n_actions):
        for q in range(action_start[a], action_start[a + 1]):
            p = by_action[q]
            for g in range(groups):
                gg, xg, out = grad[g, p], x[g // per, row[p]], gw[g, a]
                gb[g, a] += gg
                for i in range(width):
                    out[i] += gg * xg[i]
