"""What every part of one environment's evaluation reads (the data, the ensemble, the ranked
test subsets) and fills (its tables and metrics).

Why one object: the accuracy tables, the cross accuracy, the rollouts and the corruption study
all read the same dozen inputs and add to the same two dicts; passing them one by one made every
part's signature a long list that had to be kept in step.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from pcpg_dist.common.errors import DataError
from pcpg_dist.config.stages import EvalConfig
from pcpg_dist.dataset import Dataset
from pcpg_dist.domains.base import DomainHooks
from pcpg_dist.domains.defaults import score_dataset
from pcpg_dist.stages.bc import TrainedCells
from pcpg_dist.stages.evaluation.results import mean_std
from pcpg_dist.stages.evaluation.scoring import Scorer, cell_table
from pcpg_dist.stages.ranking import RankConfig, ScoreFn, ranked_last, threshold


@dataclass(eq=False)
class EvalContext:
    """One environment's evaluation inputs, and the tables and metrics it has produced so far."""

    dataset: Dataset
    labels: np.ndarray  # (trajectories,) cluster of every trajectory
    k: int
    test_idx: np.ndarray  # sorted
    train_idx: np.ndarray
    trained: TrainedCells
    cells: dict[tuple, int]  # cell index by (kind, k, p, seed, c)
    seeds: list[int]
    ps: list[float]
    scores: np.ndarray  # Step B's score of every trajectory
    last: np.ndarray | None  # ranked last by the style margin, where rank_cfg asks
    ids: np.ndarray  # trajectory ids (ties in the ranking)
    h_test: dict[tuple[int, float], np.ndarray]  # H_{k,p}^test
    scorer: Scorer
    rank_cfg: RankConfig
    cfg: EvalConfig
    hooks: DomainHooks
    tables: dict[str, pd.DataFrame] = field(default_factory=dict)
    metrics: dict[str, float] = field(default_factory=dict)

    def put(self, name: str, values: list[float]) -> None:
        """``name`` and ``name/std``: the mean and std of ``values`` (over seeds, mostly)."""
        mean, std = mean_std(values)
        self.metrics[name], self.metrics[f"{name}/std"] = mean, std


def build_context(
    dataset: Dataset,
    labels: np.ndarray,
    test_idx: np.ndarray,
    trained: TrainedCells,
    rank_cfg: RankConfig,
    cfg: EvalConfig,
    hooks: DomainHooks | None,
    score: ScoreFn | None,
    k: int | None,
    margins: np.ndarray | None,
) -> EvalContext:
    """Check the inputs, rank the test trajectories as the training ones were, and predict every
    cell on the test rows once."""
    hooks = hooks or DomainHooks()
    labels = np.asarray(labels, np.int64)
    if labels.shape != (dataset.n_trajectories,):
        raise DataError(f"labels must have shape ({dataset.n_trajectories},), got {labels.shape}")
    k = int(labels.max()) + 1 if k is None else k
    test_idx = np.sort(np.asarray(test_idx, np.int64))
    if not len(test_idx):
        raise DataError("evaluation needs test trajectories (ranking.test_fraction > 0)")
    train_idx = np.setdiff1d(np.arange(dataset.n_trajectories), test_idx)
    cells = cell_table(trained)
    seeds = sorted({s.seed for s in trained.specs})
    ps = [float(p) for p in rank_cfg.ps]
    scores = score_dataset(dataset, rank_cfg, score)
    last = ranked_last(margins, rank_cfg, dataset)
    ids = dataset.trajectory_ids
    h_test = threshold(labels, test_idx, scores, ids, ps, k, last)
    scorer = Scorer(dataset, test_idx, trained)
    ctx = EvalContext(
        dataset, labels, k, test_idx, train_idx, trained, cells, seeds, ps, scores, last, ids,
        h_test, scorer, rank_cfg, cfg, hooks,
    )  # fmt: skip
    if last is not None:
        ctx.metrics["ranking/ranked_last"] = float(last.mean())
    return ctx
