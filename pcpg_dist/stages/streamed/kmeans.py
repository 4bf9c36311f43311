"""k-means over streamed feature rows, from per-block sufficient statistics.

The fit is Lloyd's algorithm with every step a sum over blocks: :func:`moments` (count, sum and
sum of squares, to standardise the features), :func:`lloyd_stats` (per-centre counts and sums
and the inertia) and :func:`lloyd_update` (new centres from the reduced statistics). The start
is k-means++ with several restarts on a seeded sample (:func:`initial_centres`), so a fit over a
million trajectories costs a few passes over the feature table and the driver holds only k x F
numbers. The labels do not depend on how the rows are cut into blocks.
"""

from __future__ import annotations

import numpy as np


def moments(x: np.ndarray) -> np.ndarray:
    """``[count, sum(F), sum of squares(F)]`` of a block's rows, one float64 vector."""
    x = x.astype(np.float64)
    return np.concatenate([[len(x)], x.sum(0), (x * x).sum(0)])


def scaling(total: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reduced :func:`moments` -> (mean, scale) that standardise every feature (scale 1 where a
    feature is constant)."""
    n = max(total[0], 1.0)
    f = (len(total) - 1) // 2
    mean = total[1 : 1 + f] / n
    var = np.maximum(total[1 + f :] / n - mean * mean, 0.0)
    scale = np.sqrt(var)
    return mean, np.where(scale > 1e-12, scale, 1.0)


def distances(z: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Squared Euclidean distances (rows, k)."""
    from sklearn.metrics.pairwise import euclidean_distances

    return euclidean_distances(z, centres, squared=True)


def assign(z: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """The nearest centre of every (standardised) row."""
    return distances(z, centres).argmin(1)


def lloyd_stats(z: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """``[counts(k), sums(k*F), inertia]`` of a block, one float64 vector."""
    d = distances(z, centres)
    labels = d.argmin(1)
    k, f = centres.shape
    counts = np.bincount(labels, minlength=k).astype(np.float64)
    sums = np.zeros((k, f))
    np.add.at(sums, labels, z)
    return np.concatenate([counts, sums.ravel(), [d[np.arange(len(z)), labels].sum()]])


def lloyd_update(centres: np.ndarray, total: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Reduced :func:`lloyd_stats` -> (new centres, inertia, largest centre move). A centre that
    lost every row stays where it was."""
    k, f = centres.shape
    counts, sums = total[:k], total[k : k + k * f].reshape(k, f)
    new = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1.0)[:, None], centres)
    return new, float(total[-1]), float(np.abs(new - centres).max())


def initial_centres(sample: np.ndarray, k: int, seed: int, restarts: int = 4) -> np.ndarray:
    """k-means++ starts refined on a sample, the best of ``restarts`` by inertia."""
    from sklearn.cluster import KMeans

    if len(sample) < k:
        raise ValueError(f"{len(sample)} sampled trajectories cannot seed {k} clusters")
    fit = KMeans(n_clusters=k, n_init=restarts, random_state=seed).fit(sample)
    return fit.cluster_centers_.astype(np.float64)
