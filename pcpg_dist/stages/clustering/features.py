"""Visitation features of Step A's bag clusterers, with identical trajectories collapsed.

A trajectory becomes one sparse binary row over a vocabulary fitted on the training data:

- which distinct states it visits (a state = one distinct row of the state matrix);
- which (state, action) pairs it takes (only pairs seen in the training data get a column);
- which state it ends in (one-hot): the outcome (goal, trap, bonus flags) in a single column.

Binary, so a loop walked twice is the same route; each part is the discrete-state view of the
supervised ceiling (pcpg_dist/stages/clustering/ceiling.py), which also uses the visited states and state-actions.
Rows are L2-normalised (cosine geometry), so a long and a short trajectory of one route stay close.

Identical rows are collapsed once (:func:`dedup_rows`): E1's 4000 trajectories hold ~1350 distinct
feature rows; every clusterer then works on the distinct rows with their counts as weights.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from pcpg_dist.stages.clustering.states import row_ids, state_columns

MAX_STATES = 20_000  # most frequent distinct states kept as columns


@dataclass(frozen=True)
class BagVocabulary:
    """What the columns mean: distinct state rows, observed (state, action) keys, action count."""

    states: np.ndarray  # (V, d) float32, most frequent first
    sa_keys: np.ndarray  # (P,) int64 sorted: state_column * n_actions + action
    n_actions: int

    @property
    def width(self) -> int:
        return 2 * len(self.states) + len(self.sa_keys)


def fit_vocabulary(states: np.ndarray, actions: np.ndarray, n_actions: int) -> BagVocabulary:
    """The columns of :func:`bag_matrix`, fitted on one dataset's rows."""
    ids, first = row_ids(states)
    counts = np.bincount(ids)
    keep = np.argsort(-counts, kind="stable")[:MAX_STATES]
    vocab = np.ascontiguousarray(states, np.float32)[first[keep]]
    cols = state_columns(states, vocab)
    ok = (cols >= 0) & (actions >= 0)
    sa = np.unique(cols[ok] * n_actions + actions[ok])
    return BagVocabulary(vocab, sa.astype(np.int64), int(n_actions))


def bag_matrix(
    states: np.ndarray, offsets: np.ndarray, actions: np.ndarray, vocab: BagVocabulary
) -> sparse.csr_matrix:
    """(n trajectories, vocab.width) binary rows [visited states | state-actions | final state]."""
    n = len(offsets) - 1
    v = len(vocab.states)
    traj = np.repeat(np.arange(n), np.diff(offsets))
    cols = state_columns(states, vocab.states)
    ok = cols >= 0
    rows_s, cols_s = traj[ok], cols[ok]
    key = cols * vocab.n_actions + actions
    pos = np.searchsorted(vocab.sa_keys, key)
    pos_c = np.minimum(pos, max(len(vocab.sa_keys) - 1, 0))
    ok_sa = ok & (actions >= 0) & (len(vocab.sa_keys) > 0)
    if len(vocab.sa_keys):
        ok_sa &= vocab.sa_keys[pos_c] == key
    rows_a, cols_a = traj[ok_sa], v + pos[ok_sa]
    last = cols[offsets[1:] - 1]
    ok_f = last >= 0
    rows_f, cols_f = np.arange(n)[ok_f], v + len(vocab.sa_keys) + last[ok_f]
    r = np.concatenate([rows_s, rows_a, rows_f])
    c = np.concatenate([cols_s, cols_a, cols_f])
    m = sparse.csr_matrix((np.ones(len(r)), (r, c)), shape=(n, vocab.width))
    m.data[:] = 1.0  # visited or not
    return m


def dedup_rows(x: sparse.csr_matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(first, counts, inverse)``: one representative row per distinct row, how many share it,
    and each row's distinct index (``x[first][inverse]`` equals ``x``).

    Rows are keyed by two fixed random projections (a complex number): distinct binary rows
    collide only if both projections agree exactly.
    """
    proj = np.random.default_rng(20240917).standard_normal((x.shape[1], 2))
    h = np.asarray(x @ proj)
    key = h[:, 0] + 1j * h[:, 1]
    _, first, inv, counts = np.unique(
        key, return_index=True, return_inverse=True, return_counts=True
    )
    return first, counts.astype(np.float64), inv.reshape(-1)
