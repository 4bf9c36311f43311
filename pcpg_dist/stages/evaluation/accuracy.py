"""Fig. 4: accuracy against p, PCPG against No Clustering, random and the majority class; and
which true style each cluster stands for.

Why together: these are the tables that score agents on the test subsets of their own p, from the
predictions :class:`~pcpg_dist.stages.evaluation.scoring.Scorer` made once.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd

from pcpg_dist.dataset import Dataset
from pcpg_dist.stages.evaluation.context import EvalContext
from pcpg_dist.stages.evaluation.results import mean_std
from pcpg_dist.stages.evaluation.scoring import style_of_clusters
from pcpg_dist.stages.ranking import fmt, threshold_all


def majority_accuracy_of(dataset: Dataset, train_idx: np.ndarray) -> Callable[[np.ndarray], float]:
    """Accuracy on trajectories ``idx`` of always predicting the training split's most frequent
    action (masks ignored), from per-trajectory counts made once."""
    # per trajectory: steps with an action, and how many of them are the training majority action
    traj, acts = dataset.row_trajectory, dataset.actions
    is_step = acts >= 0
    in_train = np.isin(traj, train_idx) & is_step
    majority = int(np.bincount(acts[in_train], minlength=dataset.n_actions).argmax())
    n_steps = np.bincount(traj, weights=is_step, minlength=dataset.n_trajectories)
    n_majority = np.bincount(traj, weights=acts == majority, minlength=dataset.n_trajectories)

    def majority_accuracy(idx: np.ndarray) -> float:
        """Accuracy of always predicting the training split's most frequent action (masks ignored)."""
        steps = n_steps[idx].sum()
        return float(n_majority[idx].sum() / steps) if steps else float("nan")

    return majority_accuracy


def accuracy_table(ctx: EvalContext) -> None:
    """Table ``accuracy`` and the ``*/accuracy*`` metrics: every method at every p."""
    majority_accuracy = majority_accuracy_of(ctx.dataset, ctx.train_idx)
    rows: list[dict] = []
    for p in ctx.ps:
        _accuracy_at(ctx, p, majority_accuracy, rows)
    ctx.metrics["random/accuracy"] = ctx.scorer.random_accuracy(ctx.test_idx)
    ctx.metrics["majority/accuracy"] = majority_accuracy(ctx.test_idx)
    ctx.tables["accuracy"] = pd.DataFrame(rows)


def _accuracy_at(
    ctx: EvalContext, p: float, majority_accuracy: Callable[[np.ndarray], float], rows: list[dict]
) -> None:
    """The accuracy rows and metrics of one p (appended to ``rows`` and ``ctx.metrics``)."""
    cells, scorer, h_test, k = ctx.cells, ctx.scorer, ctx.h_test, ctx.k
    union = np.unique(np.concatenate([h_test[(c, p)] for c in range(k)]))
    pc, nc, nc_own, lead = [], [], [], []
    nc_test = threshold_all(ctx.test_idx, ctx.scores, ctx.ids, [p])[p]
    for seed in ctx.seeds:
        # a cluster without an agent (no training trajectory) is scored with No Clustering's
        pcpg = [
            (
                cells.get(("pcpg", c, p, seed, 0.0), cells.get(("nc", -1, p, seed, 0.0))),
                h_test[(c, p)],
            )
            for c in range(k)
        ]
        pcpg = [(cell, idx) for cell, idx in pcpg if cell is not None]
        if pcpg:
            pc.append(scorer.pooled(pcpg))
        base = cells.get(("nc", -1, p, seed, 0.0))
        if base is not None:
            nc.append(scorer.accuracy(base, union))
            nc_own.append(scorer.accuracy(base, nc_test))
            if pcpg:
                lead.append(scorer.paired_lead(pcpg, base))
    rnd = scorer.random_accuracy(union)
    for method, vals in (
        ("pcpg", pc),
        ("no_clustering", nc),
        ("no_clustering_own_subset", nc_own),
    ):
        if vals:
            rows.append(
                {
                    "method": method,
                    "p": p,
                    "mean": mean_std(vals)[0],
                    "std": mean_std(vals)[1],
                    "seeds": len(vals),
                }
            )
    rows.append({"method": "random", "p": p, "mean": rnd, "std": 0.0, "seeds": 0})
    maj = majority_accuracy(union)
    rows.append({"method": "majority", "p": p, "mean": maj, "std": 0.0, "seeds": 0})
    ctx.metrics[f"majority/accuracy/p{fmt(p)}"] = maj
    if pc:
        ctx.put(f"pcpg/accuracy/p{fmt(p)}", pc)
    if nc:
        ctx.put(f"baseline/accuracy/p{fmt(p)}", nc)
    if lead:  # PCPG less No Clustering, and one seed's standard error (the seeds' mean)
        ctx.metrics[f"pcpg/lead_over_nc/p{fmt(p)}"] = mean_std([v for v, _ in lead])[0]
        ctx.metrics[f"pcpg/lead_over_nc_se/p{fmt(p)}"] = mean_std([e for _, e in lead])[0]
    ctx.metrics[f"random/accuracy/p{fmt(p)}"] = rnd
    for c in range(k):
        vals = [
            scorer.accuracy(cells[("pcpg", c, p, s, 0.0)], h_test[(c, p)])
            for s in ctx.seeds
            if ("pcpg", c, p, s, 0.0) in cells
        ]
        if vals:
            ctx.put(f"pcpg/accuracy/k{c}/p{fmt(p)}", vals)


def cluster_style_table(ctx: EvalContext) -> None:
    """Table ``cluster_style`` where the true styles are known: which true style each cluster
    stands for (Tables 3-5 by style), with its size and purity."""
    dataset, labels, k = ctx.dataset, ctx.labels, ctx.k
    if (dataset.styles < 0).any():
        return
    sizes = np.bincount(labels, minlength=k)
    majority = style_of_clusters(dataset, labels, k)
    # the column "trajectories" counts each cluster's trajectories (a plain word, not a domain)
    ctx.tables["cluster_style"] = pd.DataFrame(
        dict(
            k=np.arange(k),
            style=majority,
            trajectories=sizes[:k],
            purity=[
                float(np.mean(dataset.styles[labels == c] == majority[c])) if sizes[c] else np.nan
                for c in range(k)
            ],
        )
    )


def wins_over_baseline(ctx: EvalContext) -> None:
    """Metric ``pcpg/wins_over_baseline``: the share of p where PCPG beats No Clustering."""
    metrics, ps = ctx.metrics, ctx.ps
    if any(
        f"pcpg/accuracy/p{fmt(p)}" in metrics and f"baseline/accuracy/p{fmt(p)}" in metrics
        for p in ps
    ):
        wins = [
            metrics[f"pcpg/accuracy/p{fmt(p)}"] > metrics[f"baseline/accuracy/p{fmt(p)}"]
            for p in ps
            if f"baseline/accuracy/p{fmt(p)}" in metrics
        ]
        metrics["pcpg/wins_over_baseline"] = float(np.mean(wins))
