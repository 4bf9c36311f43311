"""Step C and the evaluation over blocks: every BC cell of a unit as one stacked network.

A cell is (cluster, p) or (No Clustering, p); :mod:`.cells` says which rows train which cell. One
forward pass computes every cell's logits for the whole block (:class:`StackedPolicy`). A cell's
loss is the mean cross-entropy of its own rows; its parameters get gradient from nothing else,
and Adam is per parameter, so training cells together or apart gives the same cell. Validation
rows are never trained on: their loss, measured as the epoch passes, decides when a cell has
converged (:class:`EarlyStop`), and each cell keeps its best weights.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

EVAL_ROWS = 65_536  # rows a forward pass of the evaluation takes at a time (bounded memory)


class StackedPolicy(torch.nn.Module):
    """``C`` MLPs of the same shape, evaluated together: (rows, d) -> (C, rows, actions)."""

    def __init__(
        self,
        cells: int,
        d: int,
        n_actions: int,
        layers: int,
        width: int,
        activation: str,
        seed: int,
    ) -> None:
        super().__init__()
        gen = torch.Generator().manual_seed(seed)
        sizes = [d, *[width] * layers, n_actions]
        self.weights = torch.nn.ParameterList()
        self.biases = torch.nn.ParameterList()
        for a, b in zip(sizes[:-1], sizes[1:], strict=True):
            bound = 1.0 / np.sqrt(a)  # torch.nn.Linear's default initialisation
            self.weights.append(
                torch.nn.Parameter((torch.rand(cells, a, b, generator=gen) * 2 - 1) * bound)
            )
            self.biases.append(
                torch.nn.Parameter((torch.rand(cells, 1, b, generator=gen) * 2 - 1) * bound)
            )
        self.act = torch.tanh if activation == "tanh" else torch.relu

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = torch.einsum("bi,cio->cbo", x, self.weights[0]) + self.biases[0]
        for w, b in zip(self.weights[1:], self.biases[1:], strict=True):
            h = torch.baddbmm(b, self.act(h), w)
        return h

    def cell_state(self, i: int) -> list[np.ndarray]:
        return [p.detach()[i].numpy().copy() for p in (*self.weights, *self.biases)]

    def load_cells(self, states: list[list[np.ndarray]]) -> None:
        with torch.no_grad():
            for j, p in enumerate((*self.weights, *self.biases)):
                p.copy_(torch.as_tensor(np.stack([s[j] for s in states])))


def cell_losses(logits: torch.Tensor, y: torch.Tensor, member: torch.Tensor) -> torch.Tensor:
    """(C,) summed cross-entropy of each cell's member rows."""
    c, b, a = logits.shape
    ce = torch.nn.functional.cross_entropy(
        logits.reshape(c * b, a), y.repeat(c), reduction="none"
    ).reshape(c, b)
    return (ce * member).sum(1)


@dataclass
class EarlyStop:
    """Stops a cell when its validation loss has not improved by ``tol`` (relative) for
    ``patience`` epochs, keeping the weights of its best epoch."""

    cells: int
    tol: float = 1e-3
    patience: int = 1
    best: np.ndarray = field(init=False)
    waited: np.ndarray = field(init=False)
    best_states: list = field(init=False)

    def __post_init__(self) -> None:
        self.best = np.full(self.cells, np.inf)
        self.waited = np.zeros(self.cells, np.int64)
        self.best_states = [None] * self.cells

    def update(self, loss: np.ndarray, model: StackedPolicy) -> None:
        for i, value in enumerate(loss):
            if self.done[i]:
                continue
            if value < self.best[i] * (1.0 - self.tol) or self.best_states[i] is None:
                self.best[i], self.waited[i] = value, 0
                self.best_states[i] = model.cell_state(i)
            else:
                self.waited[i] += 1

    @property
    def done(self) -> np.ndarray:
        return self.waited >= self.patience

    @property
    def all_done(self) -> bool:
        return bool(self.done.all())


def accuracy_counts(
    model: StackedPolicy, x: np.ndarray, y: np.ndarray, cluster: np.ndarray, k: int
) -> np.ndarray:
    """``[correct(C*k), rows(k)]``: each cell's correct predictions on the test rows of each
    cluster, and the rows of each cluster."""
    correct = None
    for lo in range(0, len(y), EVAL_ROWS):
        with torch.no_grad():
            pred = model(torch.as_tensor(x[lo : lo + EVAL_ROWS])).argmax(-1).numpy()  # (C, rows)
        hit = pred == y[None, lo : lo + EVAL_ROWS]
        if correct is None:
            correct = np.zeros((len(pred), k))
        part = cluster[lo : lo + EVAL_ROWS]
        for c in range(k):
            correct[:, c] += hit[:, part == c].sum(1)
    if correct is None:
        correct = np.zeros((len(model.weights[0]), k))
    return np.concatenate([correct.ravel(), np.bincount(cluster, minlength=k).astype(np.float64)])
