"""The torch engine of Step C: many small policies trained in one vectorised pass (GPU or CPU).

Why vectorised: a 3x5 MLP is microseconds of arithmetic, so a per-model training loop is all
Python and autograd overhead. Here every cell's parameters are one slice of stacked tensors,
the forward and backward passes are hand-written ``torch.baddbmm``/``bmm`` calls over all cells at
once (cells padded to a common row count with zero-weight rows), and Adam runs on one flat
(cells, params) buffer. Adam is elementwise, so a stacked Adam is exactly independent Adams; the
loss of each cell is the weighted mean over its own rows, so padding and neighbours cannot leak
into it. Training is full batch and deterministic: the only randomness is the initialisation,
drawn from each cell's own seed.

Cells are grouped into buckets of similar row counts before padding, so a few large cells (No
Clustering at p = 1) do not make every small cell pay for their padding.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from pcpg_dist.config.stages import BCConfig
from pcpg_dist.stages.bc.network import INVALID_LOGIT
from pcpg_dist.stages.ranking import Cell


def buckets(rows: Sequence[int], overhead: int) -> list[list[int]]:
    """Group cells (by index) into runs of similar row counts, minimising padded rows plus
    ``overhead`` per group (a dynamic programme over the cells sorted by size)."""
    order = sorted(range(len(rows)), key=lambda i: rows[i])
    sizes = [rows[i] for i in order]
    n = len(sizes)
    best = [0.0] + [float("inf")] * n
    cut = [0] * (n + 1)
    for j in range(1, n + 1):  # group order[i:j] is padded to sizes[j-1]
        for i in range(j):
            cost = best[i] + overhead + (j - i) * sizes[j - 1]
            if cost < best[j]:
                best[j], cut[j] = cost, i
    groups, j = [], n
    while j > 0:
        groups.append(order[cut[j] : j])
        j = cut[j]
    return groups[::-1]


def _padded_rows(
    cells: list[Cell], data: list[tuple[np.ndarray, ...]], sizes: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(inputs, logit masks, weighted one-hot targets, row weights) of a group, every cell
    padded to the group's largest row count with rows that are all valid and weigh 0."""
    n_cells, n_rows = len(cells), max(len(x[2]) for x in data)
    d, n_actions = sizes[0], sizes[-1]
    x = np.zeros((n_cells, n_rows, d), np.float32)
    neg = np.zeros((n_cells, n_rows, n_actions), np.float32)  # padding rows: all valid, weight 0
    target = np.zeros((n_cells, n_rows, n_actions), np.float64)
    weight = np.zeros((n_cells, n_rows, 1), np.float64)
    for j, (cell, (s, v, a, w)) in enumerate(zip(cells, data, strict=True)):
        n = len(a)
        x[j, :n] = (s - cell.mean) / cell.std
        neg[j, :n] = np.where(v, 0.0, INVALID_LOGIT)
        wn = w / w.sum()  # each cell's loss is the mean over its own samples
        weight[j, :n, 0] = wn
        target[j, np.arange(n), a] = wn
    return x, neg, target, weight


def train_group(
    cells: list[Cell],
    data: list[tuple[np.ndarray, ...]],
    sizes: tuple[int, ...],
    cfg: BCConfig,
    device: torch.device,
    dtype: torch.dtype,
    starts: list[np.ndarray],
) -> tuple[dict, np.ndarray]:
    """Train one bucket of cells full batch for ``cfg.epochs`` Adam steps; (parameters by name,
    final loss per cell)."""
    n_cells = len(cells)

    def t(a: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(a, dtype=dtype, device=device)

    x, neg, target, weight = (t(a) for a in _padded_rows(cells, data, sizes))
    # one flat (cells, P) buffer for parameters, gradients and Adam moments; W/b are views into it
    shapes = [
        (a, b) if i % 2 == 0 else (1, b)
        for a, b in zip(sizes[:-1], sizes[1:], strict=True)
        for i in range(2)
    ]
    numel = [a * b for a, b in shapes]
    offs = np.r_[0, np.cumsum(numel)]
    flat = np.stack(starts)
    theta, grad = t(flat), torch.zeros(n_cells, int(offs[-1]), dtype=dtype, device=device)

    def views(buf: torch.Tensor) -> list[torch.Tensor]:
        return [buf[:, offs[i] : offs[i + 1]].view(n_cells, *shapes[i]) for i in range(len(shapes))]

    ps, gs = views(theta), views(grad)
    loss = _adam_full_batch(x, neg, target, weight, ps, gs, theta, grad, len(sizes) - 1, cfg)
    out = {}
    host = [p.detach().cpu().numpy().astype(np.float32) for p in ps]
    for i in range(len(sizes) - 1):
        out[f"W{i}"] = host[2 * i]
        out[f"b{i}"] = host[2 * i + 1][:, 0, :]
    return out, loss.cpu().numpy().astype(np.float64)


def _adam_full_batch(
    x: torch.Tensor,
    neg: torch.Tensor,
    target: torch.Tensor,
    weight: torch.Tensor,
    ps: list[torch.Tensor],
    gs: list[torch.Tensor],
    theta: torch.Tensor,
    grad: torch.Tensor,
    n_layers: int,
    cfg: BCConfig,
) -> torch.Tensor:
    """Up to ``cfg.epochs`` steps of hand-written backward and Adam on ``theta`` (in place; ``ps``
    and ``gs`` are per-layer views of ``theta`` and ``grad``), each cell stopping early as in the
    numba kernel; the final loss per cell."""
    m, v = torch.zeros_like(theta), torch.zeros_like(theta)
    relu = cfg.activation == "relu"
    act_back = (
        torch.ops.aten.threshold_backward.default if relu else torch.ops.aten.tanh_backward.default
    )
    beta1, beta2 = cfg.betas

    def forward() -> tuple[list[torch.Tensor], torch.Tensor]:
        hs = [x]
        for layer in range(n_layers - 1):
            z = torch.baddbmm(ps[2 * layer + 1], hs[-1], ps[2 * layer])
            hs.append(z.relu_() if relu else z.tanh_())
        logits = torch.baddbmm(ps[-1], hs[-1], ps[-2]).add_(neg)
        return hs, logits

    def loss() -> torch.Tensor:
        _, logits = forward()
        return -(torch.log_softmax(logits, dim=-1) * target).sum(dim=(1, 2))

    window = cfg.stop_window if cfg.stop_tol > 0 else 0
    last = torch.full((theta.shape[0],), torch.inf, dtype=theta.dtype, device=theta.device)
    live = None  # (cells, 1) 1 while a cell trains, 0 once it stopped (None: all train)
    with torch.no_grad():
        for step in range(1, cfg.epochs + 1):
            hs, logits = forward()
            # d(weighted mean CE)/d logits = w * softmax - w * onehot
            g = torch.softmax(logits, dim=-1).mul_(weight).sub_(target)
            for layer in range(n_layers - 1, -1, -1):
                gs[2 * layer].copy_(torch.bmm(hs[layer].transpose(1, 2), g))
                gs[2 * layer + 1].copy_(g.sum(dim=1, keepdim=True))
                if layer:
                    gh = torch.bmm(g, ps[2 * layer].transpose(1, 2))
                    g = act_back(gh, hs[layer], 0) if relu else act_back(gh, hs[layer])
            # Adam, exactly as torch.optim.Adam (no weight decay, no amsgrad)
            m.mul_(beta1).add_(grad, alpha=1 - beta1)
            v.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
            bc1, bc2 = 1 - beta1**step, 1 - beta2**step
            denom = (v.sqrt() / bc2**0.5).add_(cfg.eps)
            theta.addcdiv_(m if live is None else m * live, denom, value=-cfg.lr / bc1)
            if window and step % window == 0:  # early stopping, as the numba kernel
                now = loss()
                done = (last - now) < cfg.stop_tol
                if live is not None:
                    done &= live[:, 0] > 0
                if done.any():
                    live = torch.ones_like(last)[:, None] if live is None else live
                    live[done] = 0
                    if not live.any():
                        break
                last = torch.where(done, last, now)
        return loss()
