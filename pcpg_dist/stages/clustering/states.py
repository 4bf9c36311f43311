"""The trajectories as Step A reads them: checked state sequences, distinct state rows (ids,
vocabularies, columns) and the cheap per-trajectory features (summaries, visited states).

Every clusterer, the saved model and the supervised ceiling start here; numpy only (scipy and
sklearn where a sparse matrix is built), so nothing here pulls in torch.
"""

from __future__ import annotations

import numpy as np

from pcpg_dist.common.errors import DataError

MAX_VOCAB = 20_000  # visits_kmeans: most frequent distinct states kept as features


def checked_sequences(dataset, where: str = "clustering") -> tuple[np.ndarray, np.ndarray]:
    """``(states float32 (rows, d), offsets (n+1,))`` of a dataset, checked for what we rely on.

    The :class:`Dataset` constructor validates too, but its arrays are mutable numpy arrays, so a
    caller can break them afterwards; a NaN reaching the LSTM would silently poison every weight.
    """
    states = np.asarray(dataset.states, dtype=np.float32)
    offsets = np.asarray(dataset.offsets, dtype=np.int64)
    n = len(offsets) - 1
    if n < 1:
        raise DataError(f"{where}: dataset {dataset.domain}-{dataset.env} has no trajectories")
    if states.ndim != 2 or states.shape[1] < 1:
        raise DataError(f"{where}: states must have shape (rows, d>=1), got {states.shape}")
    if (np.diff(offsets) < 1).any() or offsets[0] != 0 or offsets[-1] != len(states):
        raise DataError(
            f"{where}: offsets must rise from 0 to {len(states)}; every trajectory needs a state"
        )
    bad = ~np.isfinite(states)
    if bad.any():
        row = int(np.nonzero(bad.any(axis=1))[0][0])
        traj = int(np.searchsorted(offsets, row, side="right") - 1)
        raise DataError(
            f"{where}: trajectory {traj} (row {row}) has a NaN or infinite state feature"
        )
    return states, offsets


def summary_features(states: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Per trajectory: [length, final state, mean state] — the cheap baseline's whole view."""
    lengths = np.diff(offsets)
    sums = np.add.reduceat(states.astype(np.float64), offsets[:-1], axis=0)
    final = states[offsets[1:] - 1].astype(np.float64)
    return np.column_stack([lengths.astype(np.float64), final, sums / lengths[:, None]])


def row_ids(states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Id of every distinct state row (0..u-1, in sorted order of a row hash) and each id's first row.

    Rows are hashed by two fixed random projections (a complex number each), then sorted once: a
    million 64-wide rows take a second, where ``np.unique(axis=0)`` takes minutes. Two different
    rows share an id only if both projections collide exactly (never seen; harmless for features).
    """
    x = np.ascontiguousarray(states, np.float64)
    proj = np.random.default_rng(20231013).standard_normal((x.shape[1], 2))
    h = x @ proj
    key = h[:, 0] + 1j * h[:, 1]
    _, first, inv = np.unique(key, return_index=True, return_inverse=True)
    return inv.reshape(-1).astype(np.int64), first


def state_columns(states: np.ndarray, vocab_states: np.ndarray) -> np.ndarray:
    """Column of every state row in ``vocab_states`` (-1 = not in the vocabulary)."""
    both = np.concatenate([vocab_states.astype(np.float32), np.asarray(states, np.float32)])
    inv, _ = row_ids(both)
    col_of = np.full(inv.max() + 1, -1, np.int64)
    col_of[inv[: len(vocab_states)]] = np.arange(len(vocab_states))
    return col_of[inv[len(vocab_states) :]]


def mostly_distinct_states(states: np.ndarray) -> bool:
    """Whether more than half the state rows are distinct (continuous states: bags are useless)."""
    _, first = row_ids(states)
    return len(first) > 0.5 * len(states)


def state_vocabulary(states: np.ndarray) -> np.ndarray:
    """The distinct state rows, most frequent first (at most MAX_VOCAB): visits_kmeans' features."""
    ids, first = row_ids(states)
    counts = np.bincount(ids)
    keep = np.argsort(-counts, kind="stable")[:MAX_VOCAB]
    return np.ascontiguousarray(states, np.float32)[first[keep]]


def visit_features(states: np.ndarray, offsets: np.ndarray, vocab: np.ndarray):
    """(n, V) sparse, rows L2-normalised: which vocabulary states each trajectory visits.

    Binary (visited or not) so a loop walked twice is the same route; normalised so a long
    trajectory and a short one of the same route stay close (cosine geometry for k-means).
    """
    from scipy import sparse
    from sklearn.preprocessing import normalize

    cols = state_columns(states, vocab)
    traj = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    ok = cols >= 0
    m = sparse.csr_matrix(
        (np.ones(int(ok.sum())), (traj[ok], cols[ok])), shape=(len(offsets) - 1, len(vocab))
    )
    m.data[:] = 1.0
    return normalize(m)


def fit_normaliser(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column mean and std; constant columns get std 1 so they stay finite (and stay zero)."""
    mean = x.mean(axis=0)
    std = x.std(axis=0)
    std = np.where(std > 1e-6, std, 1.0)
    return mean.astype(np.float32), std.astype(np.float32)
