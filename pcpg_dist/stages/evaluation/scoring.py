"""Teacher-forced accuracy of every trained cell on the test trajectories, and what a cell stands
for (its kind, cluster, p, seed and corruption level; the majority true style of its cluster).

Why here: every table of the evaluation scores agents on subsets of the same test rows, so the
predictions are made once (:class:`Scorer`) and the subsets are summed from them.
"""

from __future__ import annotations

import numpy as np

from pcpg_dist.common.errors import DataError
from pcpg_dist.dataset import Dataset
from pcpg_dist.stages.bc import TrainedCells


class Scorer:
    """Per-trajectory correct-prediction counts of every cell on the test trajectories.

    Predictions depend on the state and mask only, so each distinct test row is predicted once.
    """

    def __init__(self, dataset: Dataset, test_idx: np.ndarray, trained: TrainedCells):
        if dataset.state_dim != trained.state_dim:
            raise DataError(
                f"dataset {dataset.env} has state width {dataset.state_dim}, the "
                f"models expect {trained.state_dim}"
            )
        self.test_idx = np.asarray(test_idx, np.int64)
        test = dataset.subset(self.test_idx)
        rows = test.step_rows
        valid = test.valid_mask[rows]
        key = np.concatenate([test.states[rows].view(np.int32), valid], axis=1)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        traj = test.row_trajectory[rows]
        n = test.n_trajectories
        self.steps = np.bincount(traj, minlength=n).astype(np.float64)
        self.random = np.bincount(traj, weights=1.0 / valid.sum(axis=1), minlength=n)
        self.correct = np.zeros((len(trained.specs), n))
        for i in range(len(trained.specs)):
            pred = trained.predict(test.states[rows][first], valid[first], i)[inverse]
            self.correct[i] = np.bincount(traj, weights=pred == test.actions[rows], minlength=n)
        self.position = {int(t): j for j, t in enumerate(self.test_idx)}

    def local(self, idx: np.ndarray) -> np.ndarray:
        """Dataset positions -> positions among the test trajectories."""
        return np.array([self.position[int(i)] for i in idx], np.int64)

    def accuracy(self, cell: int, idx: np.ndarray) -> float:
        loc = self.local(idx)
        steps = self.steps[loc].sum()
        return float(self.correct[cell, loc].sum() / steps) if steps else float("nan")

    def pooled(self, cells_and_subsets: list[tuple[int, np.ndarray]]) -> float:
        hits = sum(self.correct[c, self.local(i)].sum() for c, i in cells_and_subsets)
        steps = sum(self.steps[self.local(i)].sum() for _, i in cells_and_subsets)
        return float(hits / steps) if steps else float("nan")

    def paired_lead(
        self, cells_and_subsets: list[tuple[int, np.ndarray]], base: int
    ) -> tuple[float, float]:
        """(the cells' :meth:`pooled` accuracy on their subsets less ``base``'s on the same
        trajectories, its standard error). Both agents predict the same steps, so the error is
        the paired one, with trajectories as the units (a trajectory's steps are not
        independent draws): the ratio estimator's, linearised. NaN where it cannot be told."""
        locs = [self.local(i) for _, i in cells_and_subsets]
        diff = np.concatenate(
            [
                self.correct[c, loc] - self.correct[base, loc]
                for (c, _), loc in zip(cells_and_subsets, locs, strict=True)
            ]
        )
        steps = np.concatenate([self.steps[loc] for loc in locs])
        total, n = steps.sum(), len(steps)
        if not total:
            return float("nan"), float("nan")
        lead = diff.sum() / total
        if n < 2:
            return float(lead), float("nan")
        spread = ((diff - lead * steps) ** 2).sum() * n / (n - 1)
        return float(lead), float(np.sqrt(spread) / total)

    def random_accuracy(self, idx: np.ndarray) -> float:
        loc = self.local(idx)
        return float(self.random[loc].sum() / self.steps[loc].sum())


def cell_table(trained: TrainedCells) -> dict[tuple, int]:
    """Cell index by (kind, k, p, seed, c); a DataError where two cells are the same agent."""
    table = {}
    for i, s in enumerate(trained.specs):
        ident = (s.kind, s.k, float(s.p), s.seed, float(s.c))
        if ident in table:
            raise DataError(
                f"cells {trained.specs[table[ident]].key} and {s.key} are the same "
                f"(kind, k, p, seed, c): pass one environment's ensemble"
            )
        table[ident] = i
    return table


def style_of_clusters(dataset: Dataset, labels: np.ndarray, k: int) -> list[int]:
    """Majority true style of every cluster (identity where the styles are unknown; -1 for a
    cluster with no trajectory, possible when k exceeds the number of styles)."""
    if (dataset.styles < 0).any():
        return list(range(k))
    out = []
    for c in range(k):
        member = dataset.styles[labels == c]
        out.append(int(np.bincount(member).argmax()) if len(member) else -1)
    return out
