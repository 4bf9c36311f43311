"""The BC training loss of one cell by autograd: the independent reference the tests compare the
hand-written backward passes (both engines) and the row deduplication against."""

from __future__ import annotations

import numpy as np
import torch

from pcpg_dist.stages.cell_rows import dedupe_rows
from pcpg_dist.stages.ranking import Cell


def weighted_loss_and_grad(
    cell: Cell, params: list[np.ndarray], activation: str = "relu", dedupe: bool = True
) -> tuple[float, list[np.ndarray]]:
    """The training loss of one cell and its gradient by autograd (for tests and checks).

    Independent of the hand-written backward above, so a test can compare the two and compare
    deduplicated rows against raw ones.
    """
    s, v, a, w = (
        dedupe_rows(cell.states, cell.valid, cell.actions, cell.weights)
        if dedupe
        else (cell.states, cell.valid, cell.actions, cell.weights)
    )
    ts = [torch.tensor(p, dtype=torch.float64, requires_grad=True) for p in params]
    h = torch.tensor((s - cell.mean) / cell.std, dtype=torch.float64)
    for i in range(len(ts) // 2):
        h = h @ ts[2 * i] + ts[2 * i + 1]
        if i < len(ts) // 2 - 1:
            h = torch.relu(h) if activation == "relu" else torch.tanh(h)
    h = h.masked_fill(~torch.tensor(v), float("-inf"))
    ce = torch.nn.functional.cross_entropy(h, torch.tensor(a), reduction="none")
    wt = torch.tensor(w, dtype=torch.float64)
    loss = (ce * wt).sum() / wt.sum()
    loss.backward()
    return float(loss.detach()), [p.grad.numpy() for p in ts]
