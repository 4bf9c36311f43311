"""Table 4 and Fig. 7: how well each cluster's agent imitates every cluster's test subset (cross
accuracy), and how its per-trajectory accuracy correlates with cluster membership.

Why apart from the accuracy tables: these compare agents across clusters (a k x k matrix per
seed and p), over the clusters that have an agent at every p and seed.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pcpg_dist.stages.evaluation.context import EvalContext


def cross_tables(ctx: EvalContext) -> None:
    """Tables ``cross_accuracy(_std)``, ``correlation(_std)`` and the ``cross/*`` and
    ``correlation/*`` metrics, over the clusters that have an agent (a clusterer may leave some
    of k empty: greedy_mix does when k is above the styles its likelihood supports)."""
    cells, ps, seeds = ctx.cells, ctx.ps, ctx.seeds
    used = [
        c for c in range(ctx.k) if all(("pcpg", c, p, s, 0.0) in cells for p in ps for s in seeds)
    ]
    ctx.metrics["cross/clusters"] = float(len(used))
    if not used:
        return
    cross, corr = _cross_and_correlation(ctx, used)
    n_used = len(used)
    names = [f"k{c}" for c in used]
    for name, arr in (("cross_accuracy", cross), ("correlation", corr)):
        per_seed = arr.mean(axis=1)
        ctx.tables[name] = pd.DataFrame(per_seed.mean(axis=0), index=names, columns=names)
        ctx.tables[f"{name}_std"] = pd.DataFrame(per_seed.std(axis=0), index=names, columns=names)
    m = cross.mean(axis=(0, 1))
    off = ~np.eye(n_used, dtype=bool)
    ctx.put(
        "cross/diagonal_mean",
        list(np.diagonal(cross.mean(axis=1), axis1=1, axis2=2).mean(axis=1)),
    )
    metrics = ctx.metrics
    metrics["cross/offdiagonal_mean"] = float(m[off].mean()) if n_used > 1 else float("nan")
    metrics["cross/diagonal_is_row_max"] = float(np.mean(m.argmax(axis=1) == np.arange(n_used)))
    metrics["correlation/diagonal_mean"] = float(np.diagonal(corr.mean(axis=(0, 1))).mean())


def _cross_and_correlation(ctx: EvalContext, used: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """(seeds, ps, used, used) arrays: accuracy of cluster ``row``'s agent on cluster ``col``'s
    test subset, and the point-biserial correlation of its per-trajectory accuracy with
    membership of ``col``."""
    cells, scorer, seeds, ps = ctx.cells, ctx.scorer, ctx.seeds, ctx.ps
    n_used = len(used)
    cross = np.zeros((len(seeds), len(ps), n_used, n_used))
    corr = np.zeros_like(cross)
    test_labels = ctx.labels[ctx.test_idx]
    has_steps = scorer.steps > 0
    for a, s in enumerate(seeds):
        for b, p in enumerate(ps):
            for row, c in enumerate(used):
                i = cells[("pcpg", c, p, s, 0.0)]
                per_traj = scorer.correct[i, has_steps] / scorer.steps[has_steps]
                for col, c2 in enumerate(used):
                    cross[a, b, row, col] = scorer.accuracy(i, ctx.h_test[(c2, p)])
                    member = (test_labels[has_steps] == c2).astype(float)
                    ok = per_traj.std() > 0 and member.std() > 0
                    corr[a, b, row, col] = np.corrcoef(per_traj, member)[0, 1] if ok else 0.0
    return cross, corr
