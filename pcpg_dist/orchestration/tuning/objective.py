"""One trial's score: the per-unit pipeline of `pcpg run` on the trial's parameters, no true labels.

Accuracy alone keeps rising with k (smaller, more homogeneous subsets are easier to imitate), so
the score is ``mean PCPG accuracy - penalty * (k - 1)``: one more cluster must buy more than
``penalty`` accuracy. A clustering whose smallest cluster holds less than
``min_cluster_fraction`` of the training trajectories is pruned (a cluster that small is noise,
not a play-style).
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from pcpg_dist.common.errors import DataError
from pcpg_dist.config.stages import TuneConfig
from pcpg_dist.orchestration.tuning.space import apply_params

if TYPE_CHECKING:
    from pcpg_dist.config import ExperimentConfig
    from pcpg_dist.domains.base import Unit
    from pcpg_dist.pipeline.units import UnitClustering


def _size_check(env: str, unit: Unit, k: int, tune: TuneConfig, metrics: dict[str, float]) -> Any:
    """The ``after_cluster`` step of a trial: records the clustering's label-free metrics (and
    the ARI, reported only, never scored) and says why the trial stops when a cluster is too small."""

    def check(clustering: UnitClustering) -> str | None:
        labels = clustering.labels
        if "clustering/ari" in clustering.metrics:  # reported only, never scored
            metrics[f"{env}/ari"] = clustering.metrics["clustering/ari"]
        train_idx = unit.train_idx
        sizes = np.bincount(labels[train_idx], minlength=k)
        metrics[f"{env}/size_min_frac"] = float(sizes.min() / len(train_idx))
        metrics[f"{env}/silhouette"] = clustering.metrics.get("clustering/silhouette", float("nan"))
        if sizes.min() == 0 or sizes.min() / len(train_idx) < tune.min_cluster_fraction:
            return (
                f"{env}: smallest cluster holds {int(sizes.min())} of {len(train_idx)} training "
                f"trajectories (< min_cluster_fraction {tune.min_cluster_fraction})"
            )
        return None

    return check


def score_trial(
    datasets: dict[str, Unit], cfg: ExperimentConfig, tune: TuneConfig, params: dict[str, int]
) -> dict[str, Any]:
    """Cluster -> plan cells -> train -> held-out accuracy for each unit; no true labels.

    The same per-unit pipeline as `pcpg run` (:func:`pcpg_dist.pipeline.units.run_unit`): the
    same preprocessed input to Step A, the same held-out trajectories, the domain's own skill
    score. Returns ``{"value": score or None, "pruned": reason or None, "metrics": {...}}``. True
    styles, where the data has them, only go into the metrics (``*/ari``), never into the score.
    """
    from pcpg_dist.pipeline.units import run_unit
    from pcpg_dist.stages.ranking import fmt

    trial_cfg = apply_params(cfg, params)
    k = trial_cfg.clustering.k
    rank = trial_cfg.ranking.model_copy(update={"ps": tuple(tune.ps or trial_cfg.ranking.ps)})
    seeds = tune.seeds or trial_cfg.seeds[:1]
    eval_cfg = trial_cfg.evaluation.model_copy(update={"figures": False, "corruption_levels": ()})
    metrics: dict[str, float] = {}
    pcpg, gain = [], []
    for env, unit in datasets.items():
        result = run_unit(
            unit,
            trial_cfg,
            ceiling=False,  # it depends on the data alone, not on a trial's parameters
            confidence=False,  # a trial is scored by its objective; refits would double its cost
            rank_cfg=rank,
            eval_cfg=eval_cfg,
            seeds=seeds,
            corruption=False,
            rollouts=False,
            extras=False,
            after_cluster=_size_check(env, unit, k, tune, metrics),
        )
        if result.stopped is not None:
            return {"value": None, "metrics": metrics, "pruned": result.stopped}
        ev = result.metrics
        acc = float(np.mean([ev[f"pcpg/accuracy/p{fmt(p)}"] for p in rank.ps]))
        base = float(np.mean([ev[f"baseline/accuracy/p{fmt(p)}"] for p in rank.ps]))
        metrics.update({f"{env}/pcpg_accuracy": acc, f"{env}/no_clustering_accuracy": base})
        pcpg.append(acc)
        gain.append(acc - base)
    metrics["pcpg_accuracy"], metrics["gain_over_no_clustering"] = (
        float(np.mean(pcpg)),
        float(np.mean(gain)),
    )
    value = metrics["pcpg_accuracy"] - tune.penalty * (k - 1)
    if not math.isfinite(value):
        raise DataError(f"trial {params}: the score is not finite (no test steps?)")
    metrics["score"] = value
    return {"value": value, "pruned": None, "metrics": metrics}


def trial_task(
    datasets: dict[str, Unit],
    cfg: ExperimentConfig,
    tune: TuneConfig,
    params: dict[str, int],
    threads: int,
) -> dict[str, Any]:
    """One trial as a Ray task: in-process and single-threaded unless given more CPUs."""
    from pcpg_dist.common.devices import set_threads

    set_threads(threads)
    start = time.perf_counter()
    out = score_trial(datasets, cfg, tune, params)
    out["metrics"]["trial_seconds"] = time.perf_counter() - start
    return out
