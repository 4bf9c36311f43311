"""Which rows train which BC cell: a code per trajectory, read row by row (no torch here, so the
driver that plans the cells never imports it).

A cell is (cluster, p index) or (:data:`NC`, p index). Each trajectory's code holds its cluster,
whether it is held out (test) or held back for early stopping (validation), and whether it is
kept at each p in its cluster and in No Clustering.
"""

from __future__ import annotations

import numpy as np

NC = -1  # the No Clustering cell's cluster
TEST, VALIDATION = 1 << 8, 1 << 9


def code_of(
    cluster: np.ndarray,
    test: np.ndarray,
    validation: np.ndarray,
    kept_cluster: list[np.ndarray],
    kept_nc: list[np.ndarray],
) -> np.ndarray:
    """One int64 per trajectory: cluster (bits 0-7), test, validation, then per p two bits
    (kept in its cluster, kept in No Clustering)."""
    code = cluster.astype(np.int64) & 0xFF
    code |= np.where(test, TEST, 0) | np.where(validation & ~test, VALIDATION, 0)
    for i, (kc, kn) in enumerate(zip(kept_cluster, kept_nc, strict=True)):
        code |= np.where(kc, 1 << (10 + 2 * i), 0) | np.where(kn, 1 << (11 + 2 * i), 0)
    return code


def cluster_of(code: np.ndarray) -> np.ndarray:
    """Each code's cluster (its low byte)."""
    return (code & 0xFF).astype(np.int64)


def membership(code: np.ndarray, cells: list[tuple[int, int]]) -> np.ndarray:
    """(cells, rows) bool: the training and validation rows of each (cluster, p index) cell."""
    train, cluster = (code & TEST) == 0, cluster_of(code)
    out = np.empty((len(cells), len(code)), bool)
    for i, (c, pi) in enumerate(cells):
        if c == NC:
            out[i] = train & ((code >> (11 + 2 * pi)) & 1).astype(bool)
        else:
            kept = ((code >> (10 + 2 * pi)) & 1).astype(bool)
            out[i] = train & kept & (cluster == c)
    return out
