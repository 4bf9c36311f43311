"""The training rows of a subset of trajectories, deduplicated: what one BC cell trains on.

Equal (state, valid mask, action) rows collapse into one row whose weight is their count; a
weighted loss over distinct rows equals the mean over raw rows. Many cells of an environment draw
on the same rows, so the distinct rows are found once per environment and each subset once.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from pcpg_dist.common.errors import DataError

if TYPE_CHECKING:
    from pcpg_dist.dataset import Dataset


def dedupe_rows(
    states: np.ndarray,
    valid: np.ndarray,
    actions: np.ndarray,
    weights: np.ndarray | None = None,
    return_inverse: bool = False,
) -> tuple[np.ndarray, ...]:
    """Collapse equal (state, valid, action) rows into one row whose weight is their total.

    A weighted mean of per-row losses over distinct rows equals the mean over raw rows (and so
    does its gradient): GridWorld has at most 400 states, so this shrinks ~10^4 steps to ~10^2.
    With ``return_inverse`` also returns, per input row, the index of its distinct row.
    """
    weights = np.ones(len(actions)) if weights is None else np.asarray(weights, np.float64)
    states = np.ascontiguousarray(states, np.float32)
    key = np.concatenate(
        [
            states.view(np.int32).astype(np.int64),
            _mask_key(valid),
            actions[:, None].astype(np.int64),
        ],
        axis=1,
    )
    uniq, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    out = (
        states[first],
        valid[first],
        actions[first],
        np.bincount(inverse, weights=weights, minlength=len(uniq)),
    )
    return (*out, inverse) if return_inverse else out


def _mask_key(valid: np.ndarray) -> np.ndarray:
    """The valid masks (n, A) as int64 key columns, 32 actions a column: big-endian bits in
    big-endian words sort as the bits themselves do, so the distinct rows come out in the same
    order as with a column per action (4,672 actions: 146 columns instead of 4,672)."""
    packed = np.packbits(np.asarray(valid, bool), axis=1)
    packed = np.pad(packed, ((0, 0), (0, -packed.shape[1] % 4)))
    return packed.view(">u4").astype(np.int64)


class SubsetRows:
    """The training rows of a subset of trajectories: ``(states, valid, actions, weights)``.

    With ``dedupe`` the distinct (state, valid, action) rows of the whole environment are found
    once; a subset's rows and counts are then one bincount. A subset asked for twice (the same
    trajectories at several seeds) is computed once."""

    def __init__(self, dataset: Dataset, dedupe: bool) -> None:
        self.dataset, self.dedupe = dataset, dedupe
        self.row_traj = dataset.row_trajectory
        self.steps = dataset.step_rows
        if dedupe:
            self.d_states, self.d_valid, self.d_actions, _, self.inverse = dedupe_rows(
                dataset.states[self.steps],
                dataset.valid_mask[self.steps],
                dataset.actions[self.steps],
                return_inverse=True,
            )
        self.cache: dict[bytes, tuple[np.ndarray, ...]] = {}

    def __call__(self, idx: np.ndarray, what: str) -> tuple[np.ndarray, ...]:
        dataset, steps = self.dataset, self.steps
        if idx.size == 0:
            raise DataError(
                f"dataset {dataset.domain}-{dataset.env}: subset {what} is empty "
                f"(no training trajectory carries that label)"
            )
        h = idx.tobytes()
        if h not in self.cache:
            member = np.zeros(dataset.n_trajectories, bool)
            member[idx] = True
            sel = member[self.row_traj[steps]]
            if self.dedupe:
                counts = np.bincount(self.inverse[sel], minlength=len(self.d_actions)).astype(
                    np.float64
                )
                keep = np.nonzero(counts)[0]
                self.cache[h] = (
                    self.d_states[keep],
                    self.d_valid[keep],
                    self.d_actions[keep],
                    counts[keep],
                )
            else:
                r = steps[sel]
                self.cache[h] = (
                    dataset.states[r],
                    dataset.valid_mask[r],
                    dataset.actions[r],
                    np.ones(len(r)),
                )
        return self.cache[h]
