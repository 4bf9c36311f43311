"""Everything the paper reports about the trained agents, for one environment at a time.

Generic over domains: accuracy tables need only the Dataset and the ensemble; rollouts, rewards
and drawings come from callables a domain passes in (:class:`DomainHooks`). Definitions (also in
docs/bc_and_evaluation.md):

- *Accuracy* of a model on a set of trajectories: teacher-forced greedy prediction over all their
  step rows (action >= 0), pooled (micro average). PCPG at p pools pi_{k,p} on H_{k,p}^test over
  k; No Clustering at p is scored on the *same* rows (the union of the H_{k,p}^test), so the two
  are compared on identical data. Random = mean of 1/|valid actions| over those rows.
- *Cross accuracy* (Table 4): M[k, k'] = accuracy of pi_{k,p} on H_{k',p}^test, mean over p, seeds.
- *Correlation* (Fig. 7): C[k, k'] = Pearson correlation, over the test trajectories, between
  pi_{k,p}'s per-trajectory accuracy and the indicator "trajectory is in cluster k'" (a
  point-biserial correlation: > 0 when the model imitates that cluster better than the rest),
  mean over p and seeds.
- *Reward distance* (Table 3): |mean return of pi_k's rollouts under R_{style(k)} - optimal|,
  where style(k) is the majority true style of cluster k (identity when styles are unknown).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pcpg_dist.config.stages import EvalConfig
from pcpg_dist.dataset import Dataset
from pcpg_dist.domains.base import DomainHooks
from pcpg_dist.stages.bc import TrainedCells
from pcpg_dist.stages.clustering.style_weights import style_weights_of
from pcpg_dist.stages.evaluation.accuracy import (
    accuracy_table,
    cluster_style_table,
    wins_over_baseline,
)
from pcpg_dist.stages.evaluation.context import build_context
from pcpg_dist.stages.evaluation.corruption import corruption_tables
from pcpg_dist.stages.evaluation.cross import cross_tables
from pcpg_dist.stages.evaluation.results import EvalResult
from pcpg_dist.stages.evaluation.rollouts import rollout_tables
from pcpg_dist.stages.evaluation.subsets import subset_length_table
from pcpg_dist.stages.evaluation.writing import write_evaluation
from pcpg_dist.stages.ranking import RankConfig, ScoreFn


def evaluate(
    dataset: Dataset,
    labels: np.ndarray,
    test_idx: np.ndarray,
    trained: TrainedCells,
    rank_cfg: RankConfig,
    cfg: EvalConfig,
    out_dir: str | Path | None = None,
    hooks: DomainHooks | None = None,
    score: ScoreFn | None = None,
    k: int | None = None,
    margins: np.ndarray | None = None,
    model=None,
) -> EvalResult:
    """Tables, metrics and figures of one environment's ensemble; written to ``out_dir``.
    ``margins``: the clustering's, for ``rank_cfg.style_margin`` (the test subsets are ranked as
    the training subsets were). ``model``: the fitted clustering
    (:class:`~pcpg_dist.stages.clustering.model.ClusterModel`), to classify each agent's
    rollouts back to a cluster (does the agent keep its style?)."""
    ctx = build_context(dataset, labels, test_idx, trained, rank_cfg, cfg, hooks, score, k, margins)
    accuracy_table(ctx)  # Fig. 4
    cluster_style_table(ctx)
    wins_over_baseline(ctx)
    cross_tables(ctx)  # Table 4 and Fig. 7
    subset_length_table(ctx)  # Fig. 6 from the data
    weights = style_weights_of(model)  # what each cluster weighs, where its moves' features said
    if weights is not None:
        ctx.tables["style_weights"] = weights
    rollout_sets: dict[tuple, Dataset] = {}
    if ctx.hooks.rollout is not None:  # Table 3, Fig. 5/6, Fig. 8
        rollout_tables(ctx, rollout_sets, model)
    if any(kind == "corrupt" for kind, *_ in ctx.cells):  # Fig. 9 / Table 5
        corruption_tables(ctx)
    figures: dict[str, Path] = {}
    if out_dir is not None:
        figures = write_evaluation(out_dir, ctx.tables, ctx.metrics, rollout_sets, ctx.hooks, cfg)
    return EvalResult(ctx.tables, ctx.metrics, figures)
