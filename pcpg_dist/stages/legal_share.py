"""When the taken actions' likelihoods are computed at the legal (row, action) pairs only.

A board or card game may have thousands of action ids of which a position allows a few dozen
(chess in PettingZoo's encoding: 4,672 ids, 20-40 legal). A dense softmax then computes almost
only masked-out logits. The clusterers' policies
(:mod:`pcpg_dist.stages.clustering.legal_actions`) and BC's numba kernel
(:mod:`pcpg_dist.stages.bc.kernel`) compute the legal pairs only where this rule says so, with
the same numbers to float rounding. Every built-in domain and every zoo game but chess has at
most 39 actions, so they keep the dense path.
"""

from __future__ import annotations

#: the legal pairs are used from this many actions ...
SPARSE_MIN_ACTIONS = 64
#: ... where at most this share of them is legal on the average row
SPARSE_MAX_SHARE = 0.125


def few_legal(n_actions: int, n_legal: int, n_rows: int) -> bool:
    """Whether ``n_rows`` rows of ``n_actions`` actions with ``n_legal`` legal (row, action)
    pairs in all are worth computing at their legal pairs only."""
    cells = n_actions * n_rows
    return n_actions >= SPARSE_MIN_ACTIONS and cells > 0 and n_legal <= SPARSE_MAX_SHARE * cells
