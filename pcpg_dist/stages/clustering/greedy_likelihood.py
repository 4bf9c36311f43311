"""The likelihood of ``greedy_mix`` (the model of :mod:`.greedy_mix`'s doc) and its coordinate
ascent: the steps as (state, action) counts, the votes of each cluster, the collapsed
log-likelihood of a labelling and the numba kernel that moves trajectories between clusters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy import sparse
from scipy.special import logsumexp

from pcpg_dist.stages.clustering.states import state_columns

#: the grid the profile likelihood is maximised over
NOISE_GRID = np.linspace(0.02, 0.5, 25)


@dataclass(frozen=True)
class Steps:
    """The steps of a dataset as the model sees them: per trajectory, counts of (state, action)."""

    counts: sparse.csr_matrix  # (n, S * A) how often trajectory i took action a in state s
    valid: np.ndarray  # (S, A) bool: the valid actions of each state
    n_actions: int

    @property
    def n_states(self) -> int:
        return self.valid.shape[0]

    @staticmethod
    def build(
        state_ids: np.ndarray,
        actions: np.ndarray,
        valid_rows: np.ndarray,
        row_traj: np.ndarray,
        n: int,
        n_states: int,
        n_actions: int,
    ) -> Steps:
        """From per-row state ids (-1 = unknown state, skipped), actions (-1 = none), valid masks."""
        step = (actions >= 0) & (state_ids >= 0)
        s, a = state_ids[step], actions[step].astype(np.int64)
        valid = np.zeros((n_states, n_actions), bool)
        valid[s] = np.asarray(valid_rows, bool)[step]
        valid[s, a] = True  # an action taken is valid, whatever the mask says
        counts = sparse.csr_matrix(
            (np.ones(len(s)), (row_traj[step], s * n_actions + a)), shape=(n, n_states * n_actions)
        )
        counts.sum_duplicates()
        return Steps(counts, valid, int(n_actions))

    @staticmethod
    def of_dataset(dataset, states: np.ndarray, vocab_states: np.ndarray) -> Steps:
        """A dataset's steps over the distinct states of a bag vocabulary (other states skipped)."""
        return Steps.build(
            state_columns(states, vocab_states),
            np.asarray(dataset.actions, np.int64),
            dataset.valid,
            dataset.row_trajectory,
            dataset.n_trajectories,
            len(vocab_states),
            int(dataset.n_actions),
        )


def marginal(v: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``F`` of the module doc for vote rows ``v`` (..., A): log-mean-exp over the valid actions."""
    nv = np.maximum(valid.sum(-1), 1)
    return logsumexp(np.where(valid, v, -np.inf), axis=-1) - np.log(nv)


def _lam(steps: Steps, eps: float) -> np.ndarray:
    """(S,) the vote weight lam(eps, n(s)) of one step in each state."""
    return np.log1p((1.0 - eps) * np.maximum(steps.valid.sum(1), 1) / eps)


def vote_weights(steps: Steps, eps: float) -> sparse.csr_matrix:
    """Each trajectory's (state, action) counts times the vote weight lam(eps, n(s))."""
    c = steps.counts.tocoo()
    w = sparse.csr_matrix(
        (c.data * _lam(steps, eps)[c.col // steps.n_actions], (c.row, c.col)), shape=c.shape
    )
    w.sort_indices()
    return w


def cluster_counts(steps: Steps, labels: np.ndarray, mult: np.ndarray, k: int) -> np.ndarray:
    """(k, S, A) how often each cluster's trajectories took a in s (``mult`` = copies of each row).
    The votes at noise eps are these counts times ``_lam(steps, eps)[s]``."""
    n = len(labels)
    m = sparse.csr_matrix((mult, (labels, np.arange(n))), shape=(k, n))
    return np.asarray((m @ steps.counts).todense()).reshape(k, steps.n_states, steps.n_actions)


def votes(steps: Steps, labels: np.ndarray, mult: np.ndarray, k: int, eps: float) -> np.ndarray:
    """(k, S, A) summed vote weights of each cluster's steps at noise ``eps``."""
    return cluster_counts(steps, labels, mult, k) * _lam(steps, eps)[None, :, None]


def _size_terms(sizes: np.ndarray) -> float:
    nz = sizes[sizes > 0]
    return float((nz * np.log(nz / nz.sum())).sum())


def _steps_per_state(steps: Steps, mult: np.ndarray) -> np.ndarray:
    """(S,) how many steps were taken in each state (``mult`` = copies of each row)."""
    return np.asarray(steps.counts.T @ mult).reshape(steps.n_states, steps.n_actions).sum(1)


def cluster_terms(steps: Steps, counts: np.ndarray, eps: float) -> np.ndarray:
    """(k,) each cluster's sum over the seen states of F (the module doc) at noise ``eps``."""
    seen = steps.valid.any(1)
    v = counts[:, seen] * _lam(steps, eps)[seen][None, :, None]
    return marginal(v, steps.valid[seen][None]).sum(1)


def _log_likelihood(
    steps: Steps, per_state: np.ndarray, counts: np.ndarray, size_terms: float, eps: float
) -> float:
    """The module doc's formula from its parts: sum over steps of log(eps / n(s)), the clusters' F
    terms, the size prior."""
    stray = float((per_state * np.log(eps / np.maximum(steps.valid.sum(1), 1))).sum())
    return stray + float(cluster_terms(steps, counts, eps).sum()) + size_terms


def log_likelihood(steps: Steps, mult: np.ndarray, labels: np.ndarray, k: int, eps: float) -> float:
    """The collapsed log-likelihood of a labelling at noise ``eps`` (the module doc's formula)."""
    return _log_likelihood(
        steps,
        _steps_per_state(steps, mult),
        cluster_counts(steps, labels, mult, k),
        _size_terms(np.bincount(labels, mult, minlength=k)),
        eps,
    )


def profile_log_likelihood(
    steps: Steps, mult: np.ndarray, labels: np.ndarray, k: int
) -> tuple[float, float]:
    """``(max over eps of log_likelihood, that eps)`` on :data:`NOISE_GRID`."""
    per_state, counts = _steps_per_state(steps, mult), cluster_counts(steps, labels, mult, k)
    size = _size_terms(np.bincount(labels, mult, minlength=k))
    ll = [_log_likelihood(steps, per_state, counts, size, float(e)) for e in NOISE_GRID]
    i = int(np.argmax(ll))
    return ll[i], float(NOISE_GRID[i])


@numba.njit(cache=True)
def _lme(v, valid):
    """log-mean-exp of v over the valid entries (``marginal`` of one row)."""
    top, nv = -np.inf, 0
    for a in range(v.shape[0]):
        if valid[a]:
            nv += 1
            top = max(top, v[a])
    if nv == 0:
        return 0.0
    total = 0.0
    for a in range(v.shape[0]):
        if valid[a]:
            total += np.exp(v[a] - top)
    return top + np.log(total) - np.log(nv)


@numba.njit(cache=True)
def size_term(n, total):
    return n * np.log(n / total) if n > 0 else 0.0


@numba.njit(cache=True)
def _ascend(indptr, pstate, pw, valid, v, labels, mult, sizes, max_sweeps):
    """Coordinate ascent: each row (with its ``mult`` copies) moves to the cluster that raises the
    collapsed log-likelihood most; ``v`` and ``sizes`` are updated in place. Returns the sweeps."""
    k, n_states, n_actions = v.shape
    total = sizes.sum()
    tmp = np.empty(n_actions)
    f = np.empty((k, n_states))  # F of every (cluster, state), kept current as rows move
    for c in range(k):
        for s in range(n_states):
            f[c, s] = _lme(v[c, s], valid[s])
    for sweep in range(max_sweeps):
        moves = 0
        for u in range(labels.shape[0]):
            c0, m = labels[u], mult[u]
            lose = size_term(sizes[c0] - m, total) - size_term(sizes[c0], total)
            for p in range(indptr[u], indptr[u + 1]):
                s = pstate[p]
                for a in range(n_actions):
                    tmp[a] = v[c0, s, a] - m * pw[p, a]
                lose += _lme(tmp, valid[s]) - f[c0, s]
            best, best_c = 0.0, c0
            for c in range(k):
                if c == c0:
                    continue
                gain = size_term(sizes[c] + m, total) - size_term(sizes[c], total)
                for p in range(indptr[u], indptr[u + 1]):
                    s = pstate[p]
                    for a in range(n_actions):
                        tmp[a] = v[c, s, a] + m * pw[p, a]
                    gain += _lme(tmp, valid[s]) - f[c, s]
                if lose + gain > best + 1e-9:
                    best, best_c = lose + gain, c
            if best_c != c0:
                for p in range(indptr[u], indptr[u + 1]):
                    s = pstate[p]
                    for a in range(n_actions):
                        v[c0, s, a] -= m * pw[p, a]
                        v[best_c, s, a] += m * pw[p, a]
                    f[c0, s] = _lme(v[c0, s], valid[s])
                    f[best_c, s] = _lme(v[best_c, s], valid[s])
                sizes[c0] -= m
                sizes[best_c] += m
                labels[u] = best_c
                moves += 1
        if moves == 0:
            return sweep + 1
    return max_sweeps


def per_state_votes(weights: sparse.csr_matrix, n_actions: int):
    """Row u's votes grouped by state: ``(indptr (n+1,), state (P,), votes (P, A))``."""
    w = weights.tocoo()
    n_states = weights.shape[1] // n_actions
    key = w.row.astype(np.int64) * n_states + w.col // n_actions
    pairs, pair_of = np.unique(key, return_inverse=True)
    pw = np.zeros((len(pairs), n_actions))
    np.add.at(pw, (pair_of, w.col % n_actions), w.data)
    indptr = np.searchsorted(pairs // n_states, np.arange(weights.shape[0] + 1)).astype(np.int64)
    return indptr, (pairs % n_states).astype(np.int64), pw


def ascend(
    steps: Steps, mult: np.ndarray, labels: np.ndarray, k: int, eps: float, max_sweeps: int
) -> tuple[np.ndarray, int]:
    """The coordinate ascent of the module doc at noise ``eps``: ``(labels, sweeps)``."""
    w = vote_weights(steps, eps)
    labels = np.array(labels, np.int64)
    v = votes(steps, labels, mult, k, eps)
    sizes = np.bincount(labels, mult, minlength=k).astype(np.float64)
    indptr, pstate, pw = per_state_votes(w, steps.n_actions)
    sweeps = _ascend(
        indptr, pstate, pw, steps.valid, v, labels, np.asarray(mult, np.float64), sizes, max_sweeps
    )
    return labels, sweeps
