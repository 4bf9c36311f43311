"""Fig. 6 from the data: the mean length of the training subsets each agent imitates.

Why: it is the only Fig. 6 a domain without a simulator can have; beside rollouts it shows what
the agents copy.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pcpg_dist.dataset import Dataset
from pcpg_dist.stages.evaluation.context import EvalContext
from pcpg_dist.stages.ranking import fmt, threshold, threshold_all


def _length_row(dataset: Dataset, method: str, c: int, p: float, idx: np.ndarray) -> dict:
    kept = dataset.lengths[idx] - 1  # steps (actions taken), the unit of the rollouts' length
    return {
        "method": method,
        "k": c,
        "p": p,
        "mean": float(kept.mean()),
        "std": float(kept.std()),
        "n": len(idx),
    }


def subset_length_table(ctx: EvalContext) -> None:
    """Table ``subset_length`` and the ``subset/length/*`` metrics (PCPG's H_{k,p} and No
    Clustering's subsets of the training split)."""
    dataset, ps, k = ctx.dataset, ctx.ps, ctx.k
    h_train = threshold(ctx.labels, ctx.train_idx, ctx.scores, ctx.ids, ps, k, ctx.last)
    nc_train = threshold_all(ctx.train_idx, ctx.scores, ctx.ids, ps)
    subset_rows = [
        _length_row(dataset, "pcpg", c, p, h_train[(c, p)])
        for c in range(k)
        for p in ps
        if len(h_train[(c, p)])
    ]
    subset_rows += [_length_row(dataset, "nc", -1, p, nc_train[p]) for p in ps]
    ctx.tables["subset_length"] = pd.DataFrame(subset_rows)
    for row in subset_rows:
        who = "nc" if row["method"] == "nc" else f"k{row['k']}"
        ctx.metrics[f"subset/length/{who}/p{fmt(row['p'])}"] = row["mean"]
