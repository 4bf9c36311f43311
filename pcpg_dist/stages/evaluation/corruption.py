"""Fig. 9 and Table 5: the corruption study, agents trained on subsets ranked after a share ``c``
of the cluster labels was corrupted.

Why apart: it re-ranks the trajectories under each corrupted labelling (seed by seed, as the
training did) and scores the agents both on the subsets they were trained for and on the true
ones; no other table needs those labellings.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pcpg_dist.stages.evaluation.context import EvalContext
from pcpg_dist.stages.evaluation.results import mean_std
from pcpg_dist.stages.ranking import corrupt_labels, corruption_rng, fmt, threshold


def corruption_tables(ctx: EvalContext) -> None:
    """Tables ``corruption_accuracy`` and (where the domain lends rewards) ``corruption_reward``,
    with the ``corruption/*`` metrics."""
    cells, k, dataset = ctx.cells, ctx.k, ctx.dataset
    levels = sorted({c for kind, _, _, _, c in cells if kind == "corrupt"})
    ps = sorted({p for kind, _, p, _, _ in cells if kind == "corrupt"})
    h_true = threshold(ctx.labels, ctx.test_idx, ctx.scores, ctx.ids, ps, k, ctx.last)
    acc_rows, reward_rows = [], []
    # one return per true style's reward (k clusters may be more or fewer than the styles)
    n_rewards = (
        int(dataset.styles.max()) + 1 if len(dataset.styles) and dataset.styles.max() >= 0 else k
    )
    all_returns = (
        [ctx.hooks.returns(dataset, r) for r in range(n_rewards)]
        if ctx.hooks.returns is not None
        else None
    )
    for level in levels:
        acc_rows.append(_level(ctx, level, ps, h_true, all_returns, reward_rows))
    nc = [
        ctx.scorer.pooled(
            [
                (
                    cells[("nc", -1, p, s, 0.0)],
                    np.unique(np.concatenate([h_true[(c, p)] for c in range(k)])),
                )
            ]
        )
        for s in ctx.seeds
        for p in ps
        if ("nc", -1, p, s, 0.0) in cells
    ]
    if nc:
        ctx.put("corruption/baseline/accuracy", nc)
    ctx.tables["corruption_accuracy"] = pd.DataFrame(acc_rows).assign(
        baseline_mean=mean_std(nc)[0] if nc else np.nan
    )
    if reward_rows:
        raw = pd.DataFrame(reward_rows)
        cols = [f"R{r + 1}" for r in range(n_rewards)]
        mean = raw.groupby(["c", "k"])[cols].mean()
        std = raw.groupby(["c", "k"])[cols].std(ddof=0).add_suffix("_std")
        ctx.tables["corruption_reward"] = mean.join(std).reset_index()


def _level(
    ctx: EvalContext,
    level: float,
    ps: list[float],
    h_true: dict[tuple[int, float], np.ndarray],
    all_returns: list[np.ndarray] | None,
    reward_rows: list[dict],
) -> dict:
    """One corruption level: its metrics, its row of ``corruption_accuracy`` (returned) and its
    rows of per-subset mean returns (appended to ``reward_rows``)."""
    cells, k, rank_cfg = ctx.cells, ctx.k, ctx.rank_cfg
    acc, acc_true = [], []
    for seed in ctx.seeds:
        bad = corrupt_labels(
            ctx.labels,
            level,
            k,
            corruption_rng(rank_cfg.corruption_seed, seed, level),
            rank_cfg.corruption_mode,
        )
        h_bad = threshold(bad, ctx.test_idx, ctx.scores, ctx.ids, ps, k, ctx.last)
        h_train = threshold(bad, ctx.train_idx, ctx.scores, ctx.ids, ps, k, ctx.last)
        pairs = [
            (cells[("corrupt", c, p, seed, level)], h_bad[(c, p)], h_true[(c, p)])
            for c in range(k)
            for p in ps
            if ("corrupt", c, p, seed, level) in cells
        ]
        acc.append(ctx.scorer.pooled([(i, h) for i, h, _ in pairs]))
        acc_true.append(ctx.scorer.pooled([(i, h) for i, _, h in pairs]))
        if all_returns is not None:
            reward_rows += _reward_rows(level, seed, k, ps, h_train, all_returns)
    ctx.put(f"corruption/accuracy/c{fmt(level)}", acc)
    ctx.put(f"corruption/accuracy_true_subsets/c{fmt(level)}", acc_true)
    return {
        "c": level,
        "mean": mean_std(acc)[0],
        "std": mean_std(acc)[1],
        "true_subsets_mean": mean_std(acc_true)[0],
        "true_subsets_std": mean_std(acc_true)[1],
    }


def _reward_rows(
    level: float,
    seed: int,
    k: int,
    ps: list[float],
    h_train: dict[tuple[int, float], np.ndarray],
    all_returns: list[np.ndarray],
) -> list[dict]:
    """Mean return under every true style's reward of each corrupted training subset."""
    rows = []
    for c in range(k):
        for p in ps:
            members = h_train[(c, p)]
            rows.append(
                {
                    "c": level,
                    "seed": seed,
                    "k": c,
                    "p": p,
                    **{
                        f"R{r + 1}": float(all_returns[r][members].mean())
                        if len(members)
                        else float("nan")
                        for r in range(len(all_returns))
                    },
                }
            )
    return rows
