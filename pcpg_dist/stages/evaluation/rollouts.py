"""Table 3, Fig. 5/6 and Fig. 8: the agents played in the domain's simulator (where it lends one,
through :class:`~pcpg_dist.domains.base.DomainHooks`), and their distance to each style's
optimal return.

Why apart: only a simulating domain has rollouts; everything here goes through the hooks, and
each agent's episodes come from its own generator so every table of one agent plays the same
episodes.
"""

from __future__ import annotations

import zlib

import numpy as np
import pandas as pd

from pcpg_dist.dataset import Dataset
from pcpg_dist.domains.base import random_policy
from pcpg_dist.stages.evaluation.context import EvalContext
from pcpg_dist.stages.evaluation.scoring import style_of_clusters
from pcpg_dist.stages.ranking import fmt


def over_seeds(runs: pd.DataFrame, col: str) -> pd.DataFrame:
    """Mean and std of ``col`` per agent (method, k, p) over its seeds; the std with ddof 0, as
    every std pcpg reports (the metrics' ``/std``), so a CSV and metrics.json never disagree."""
    return (
        runs.groupby(["method", "k", "p"])[col]
        .agg(mean="mean", std=lambda x: x.std(ddof=0))
        .reset_index()
    )


def rollout_rng(base: int, key: str) -> np.random.Generator:
    """The rollouts' generator of the agent ``key`` (a cell key): every table of one agent's
    rollouts (the evaluation's, a domain's extras) plays the same episodes."""
    return np.random.default_rng([base, zlib.crc32(key.encode())])


def rollout_tables(ctx: EvalContext, rollout_sets: dict[tuple, Dataset], model=None) -> None:
    """Tables ``rollouts``, ``rollout_*`` and ``reward_distance`` with their metrics; one
    rollout of each cluster's first-seed agent at ``eval.reward_p`` lands in ``rollout_sets``
    (Fig. 8), keyed by (cluster, style). With the clustering's ``model``, each PCPG agent's
    rollouts are classified as `pcpg classify` would: ``rollout/style_kept/k{c}/p{p}`` is the
    share of agent c's episodes put back in cluster c (``rollout/style_kept/p{p}``: over the
    agents)."""
    styles = style_of_clusters(ctx.dataset, ctx.labels, ctx.k)
    runs = _rollout_runs(ctx, styles, rollout_sets, model)
    ctx.tables["rollouts"] = runs
    for col in ("length", "success", "return"):
        if col in runs:
            ctx.tables[f"rollout_{col}"] = over_seeds(runs, col)
    for (method, c, p), grp in runs.groupby(["method", "k", "p"]):
        who = f"k{c}" if method == "pcpg" else "nc"
        ctx.put(f"rollout/length/{who}/p{fmt(p)}", list(grp["length"]))
        ctx.put(
            f"rollout/success/{who}/p{fmt(p)}", list(grp["success"])
        )  # share of rollouts that succeed
        if "return" in grp:
            ctx.put(f"rollout/return/{who}/p{fmt(p)}", list(grp["return"]))
        if method == "pcpg" and "style_kept" in grp:
            ctx.put(f"rollout/style_kept/{who}/p{fmt(p)}", list(grp["style_kept"]))
    if "style_kept" in runs:
        for p, grp in runs[runs["method"] == "pcpg"].groupby("p"):
            ctx.put(f"rollout/style_kept/p{fmt(p)}", list(grp.groupby("seed")["style_kept"].mean()))
    if ctx.hooks.returns is None or ctx.hooks.optimal_return is None:
        return
    _reward_distance(ctx, runs, styles)


def _rollout_runs(
    ctx: EvalContext, styles: list[int], rollout_sets: dict[tuple, Dataset], model=None
) -> pd.DataFrame:
    """One row per PCPG or No Clustering agent: its rollouts' mean length, success and return
    (and, with ``model``, the share of a PCPG agent's rollouts classified to its own cluster)."""
    cfg, hooks, trained = ctx.cfg, ctx.hooks, ctx.trained
    mode = "greedy" if cfg.greedy else "sampled"
    rows = []
    for (kind, c, p, seed, _), i in sorted(ctx.cells.items(), key=lambda x: x[1]):
        if kind not in ("pcpg", "nc"):
            continue
        ds = hooks.rollout(
            trained.policy(i, cfg.greedy),
            cfg.rollouts_per_policy,
            rollout_rng(cfg.rollout_seed, trained.specs[i].key),
        )
        row = {
            "method": kind,
            "k": c,
            "p": p,
            "seed": seed,
            "actions": mode,
            "length": float((ds.lengths - 1).mean()),
            "success": float(ds.success.mean()),
        }
        if hooks.returns is None:  # no per-style rewards: the environment's own return is the score
            row["return"] = float(ds.returns.mean())
        if hooks.returns is not None and kind == "pcpg":
            row["return_own_style"] = float(hooks.returns(ds, styles[c]).mean())
        if model is not None and kind == "pcpg":
            row["style_kept"] = float((model.predict(ds) == c).mean())
        rows.append(row)
        if kind == "pcpg" and seed == ctx.seeds[0] and p == cfg.reward_p:
            rollout_sets[(c, styles[c])] = ds.subset([0])
    return pd.DataFrame(rows)


def _reward_distance(ctx: EvalContext, runs: pd.DataFrame, styles: list[int]) -> None:
    """Table ``reward_distance`` and its metrics: |mean return under the cluster's style's reward
    - that style's optimum|, for PCPG's agents and a random policy."""
    cfg, hooks = ctx.cfg, ctx.hooks
    mode = "greedy" if cfg.greedy else "sampled"
    rnd = hooks.rollout(
        random_policy, cfg.rollouts_per_policy, rollout_rng(cfg.rollout_seed, "random")
    )
    dist_rows = []
    by_style: dict[tuple[int, float], list[float]] = {}  # two clusters of one majority style pool
    for c in range(ctx.k):
        style = styles[c]
        if style < 0:  # an empty cluster: no agent, no style
            continue
        best = float(hooks.optimal_return(style))
        rnd_dist = abs(float(hooks.returns(rnd, style).mean()) - best)
        ctx.metrics[f"random/reward_distance/style{style}"] = rnd_dist
        for p in sorted({float(p) for p in runs.p}, reverse=True):
            own = runs[(runs.method == "pcpg") & (runs.k == c) & (runs.p == p)]
            if not len(own):
                continue
            dists = list(np.abs(own["return_own_style"].to_numpy() - best))
            by_style.setdefault((style, p), []).extend(dists)
            dist_rows.append(
                {
                    "k": c,
                    "style": style,
                    "p": p,
                    "optimal": best,
                    "actions": mode,
                    "pcpg_mean": float(np.mean(dists)),
                    "pcpg_std": float(np.std(dists)),
                    "random": rnd_dist,
                    "headline": p == cfg.reward_p,
                }
            )
    for (style, p), dists in by_style.items():
        ctx.put(f"reward_distance/style{style}/p{fmt(p)}", dists)
        if p == cfg.reward_p:
            ctx.put(f"reward_distance/style{style}", dists)
    ctx.tables["reward_distance"] = pd.DataFrame(dist_rows)
