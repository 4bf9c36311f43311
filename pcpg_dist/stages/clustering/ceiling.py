"""The honest ceiling of Step A: what a classifier *given* the true styles reaches.

Clustering accuracy alone does not say how much is left on the table: some datasets hold
trajectories that no method could tell apart (identical routes of two styles). The ceiling is a
5-fold cross-validated logistic regression trained with the true labels on the same trajectories,
on features a trajectory's style shows in:

- which distinct states it visits and which (state, action) pairs it takes (binary bag of visits:
  the discrete-state view, exact for grids and levels);
- its length, mean state and final state (standardised: the continuous-state view).

``gap = ceiling - clustering accuracy``: near 0 means the clusterer recovers all the style
information these features hold.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import sparse

from pcpg_dist.dataset import Dataset
from pcpg_dist.stages.clustering.states import row_ids

MAX_VOCAB = 20_000  # at most this many visited states / state-actions kept as features


def _bag(ids: np.ndarray, traj: np.ndarray, n: int) -> sparse.csr_matrix:
    """(n trajectories, vocabulary) binary: which ids each trajectory visits.

    Past :data:`MAX_VOCAB` ids only the most frequent are kept. Where the ids tied at the
    boundary count occur once each, they are all left out: an id of one row is seen by one
    trajectory, so it cannot carry a style from the training folds to a test trajectory, and
    which of them made the cut was an arbitrary order (on MiniDungeons, where most state rows
    occur once, that order moved the ceiling by up to 0.7 points). Ids tied at a larger count
    are left out whole too, unless that would keep under half the cap; then they fill it in id
    order (a fixed function of the rows' content).
    """
    uniq, inv, counts = np.unique(ids, return_inverse=True, return_counts=True)
    keep = np.argsort(-counts, kind="stable")
    if len(keep) > MAX_VOCAB:
        boundary = counts[keep[MAX_VOCAB]]
        whole = keep[counts[keep] > boundary]
        keep = whole if boundary == 1 or len(whole) >= MAX_VOCAB // 2 else keep[:MAX_VOCAB]
    col = np.full(len(uniq), -1)
    col[keep] = np.arange(len(keep))
    c = col[inv.reshape(-1)]
    ok = c >= 0
    m = sparse.csr_matrix((np.ones(ok.sum()), (traj[ok], c[ok])), shape=(n, len(keep)))
    m.data[:] = 1.0  # visited or not
    return m


def ceiling_features(ds: Dataset) -> sparse.csr_matrix:
    """The documented feature matrix (see the module doc), one row per trajectory."""
    n = ds.n_trajectories
    traj = ds.row_trajectory
    state_id, _ = row_ids(ds.states)
    sa_id = state_id * (ds.n_actions + 1) + (ds.actions + 1)
    step = ds.actions >= 0
    visits = _bag(state_id, traj, n)
    pairs = _bag(sa_id[step], traj[step], n)
    mean = np.add.reduceat(ds.states.astype(np.float64), ds.offsets[:-1]) / ds.lengths[:, None]
    final = ds.states[ds.offsets[1:] - 1].astype(np.float64)
    dense = np.column_stack([np.log(ds.lengths), mean, final])
    std = dense.std(axis=0)
    dense = (dense - dense.mean(axis=0)) / np.where(std > 1e-9, std, 1.0)
    return sparse.hstack([visits, pairs, sparse.csr_matrix(dense)], format="csr")


def gap_to_ceiling(ceiling: float, accuracy: float) -> float:
    """``ceiling - accuracy``. Both are fractions of whole trajectories (a cross-validated mean
    and a count over n), so a difference under 1e-12 is float noise: it is 0.0, never -0.0, which
    tables would print as "-0.000" ("above the ceiling")."""
    return round(ceiling - accuracy, 12) + 0.0


def supervised_ceiling(ds: Dataset, seed: int = 0, folds: int = 5) -> float:
    """Cross-validated accuracy of a logistic regression trained on the true styles (NaN without them)."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.model_selection import StratifiedKFold, cross_val_score

    y = ds.styles
    if not len(y) or (y < 0).any():
        return float("nan")
    counts = np.bincount(y)
    counts = counts[counts > 0]
    k = int(min(folds, counts.min()))
    if len(counts) < 2 or k < 2:
        return float("nan")
    x = ceiling_features(ds)
    clf = LogisticRegression(C=1.0, max_iter=2000)
    cv = StratifiedKFold(n_splits=k, shuffle=True, random_state=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # convergence chatter on separable data
        return float(cross_val_score(clf, x, y, cv=cv, n_jobs=1).mean())
