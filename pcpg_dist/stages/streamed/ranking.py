"""Step B over blocks: a split that every block computes alone, and the exact top p of each
group from per-block histograms.

The train/test split of a trajectory is a hash of its id and the split seed (SplitMix64), so
any block decides it without seeing the others, and the same id gets the same side in every
pass. A validation share of the training trajectories (for early stopping) is drawn the same
way from a second hash. A group (a cluster, or all for No Clustering) keeps its top
``ceil(p n)`` as the in-memory ranking does: a histogram of its scores (``BINS`` bins between
its lowest and highest) says in which bin the kept ones end (:func:`boundaries`); the scores in
that bin alone are gathered and ordered (:func:`exact_cuts`), ties broken by a hash of the
trajectory id (the in-memory ranking breaks them by the id itself). Only one bin's scores per
group reach the driver.
"""

from __future__ import annotations

import numpy as np

BINS = 4096
_M = np.uint64(0xFFFFFFFFFFFFFFFF)


def _splitmix(x: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        z = x + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def uniform(ids: np.ndarray, seed: int, stream: int = 0) -> np.ndarray:
    """A number in [0, 1) per trajectory id, fixed by (id, seed, stream)."""
    with np.errstate(over="ignore"):
        key = ids.astype(np.int64).view(np.uint64) ^ _splitmix(
            np.array([seed * 2 + stream], np.uint64)
        )
    return (_splitmix(key) >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def is_test(ids: np.ndarray, seed: int, test_fraction: float) -> np.ndarray:
    return uniform(ids, seed, 0) < test_fraction


def is_validation(ids: np.ndarray, seed: int, share: float) -> np.ndarray:
    """Training trajectories held back to decide when BC has converged."""
    return uniform(ids, seed, 1) < share


def score_ranges(score: np.ndarray, group: np.ndarray, groups: int) -> np.ndarray:
    """``[min(groups), max(groups)]`` of a block's scores per group (+-inf where empty)."""
    lo = np.full(groups, np.inf)
    hi = np.full(groups, -np.inf)
    np.minimum.at(lo, group, score)
    np.maximum.at(hi, group, score)
    return np.concatenate([lo, hi])


def merge_ranges(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Two blocks' :func:`score_ranges` -> the range of both."""
    g = len(a) // 2
    return np.concatenate([np.minimum(a[:g], b[:g]), np.maximum(a[g:], b[g:])])


def bins_of(score: np.ndarray, group: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Each score's bin in its group's range (the same score always falls in the same bin)."""
    width = np.where(hi > lo, hi - lo, 1.0)
    return np.clip(((score - lo[group]) / width[group] * BINS), 0, BINS - 1).astype(np.int64)


def score_histogram(
    score: np.ndarray, group: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> np.ndarray:
    """Counts of a block's scores per (group, bin), flattened."""
    counts = np.zeros(len(lo) * BINS)
    np.add.at(counts, group * BINS + bins_of(score, group, lo, hi), 1.0)
    return counts


def boundaries(hist: np.ndarray, groups: int, p: float) -> tuple[np.ndarray, np.ndarray]:
    """Per group, the bin where the top ``ceil(p n)`` end (-1: keep all) and how many of that
    bin's trajectories are among them."""
    where = np.full(groups, -1)
    need = np.zeros(groups, np.int64)
    if p >= 1.0:
        return where, need
    for g, counts in enumerate(hist.reshape(groups, BINS)):
        total = counts.sum()
        if total == 0:
            continue
        keep = max(1, int(np.ceil(p * total - 1e-9)))
        from_top = np.cumsum(counts[::-1])
        i = int(np.searchsorted(from_top, keep))
        where[g] = BINS - 1 - i
        need[g] = keep - (int(from_top[i - 1]) if i > 0 else 0)
    return where, need


def exact_cuts(
    score: np.ndarray, tiebreak: np.ndarray, group: np.ndarray, need: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """From the scores in each group's boundary bin, the (score, tie-break) of the last one kept:
    ordered by score (higher first), then by the id's hash (lower first)."""
    cut_score = np.full(len(need), -np.inf)
    cut_tie = np.full(len(need), np.inf)
    for g in np.flatnonzero(need > 0):
        mine = group == g
        order = np.lexsort((tiebreak[mine], -score[mine]))
        last = order[need[g] - 1]
        cut_score[g], cut_tie[g] = score[mine][last], tiebreak[mine][last]
    return cut_score, cut_tie


def is_kept(
    score: np.ndarray, tiebreak: np.ndarray, cut_score: np.ndarray, cut_tie: np.ndarray
) -> np.ndarray:
    """The top ``ceil(p n)`` of each group: above the cut, or tied with it and no later in the
    tie-break order (``cut_*`` indexed per row)."""
    return (score > cut_score) | ((score == cut_score) & (tiebreak <= cut_tie))
