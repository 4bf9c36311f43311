"""One unit through the stages: cluster (Step A) -> plan cells (Step B) -> train (Step C) -> evaluate.

Pure functions of a :class:`~pcpg_dist.domains.base.Unit` and the experiment config: no Ray, no
cache, no MLflow. `pcpg run` calls them from Ray tasks with a content-keyed cache around each, and
`pcpg tune`, `pcpg cluster` and a notebook call the same functions, so every entry point clusters
the same preprocessed input, ranks by the domain's skill score and evaluates the same way.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pcpg_dist.domains import contract
from pcpg_dist.domains.base import Unit


@dataclass
class UnitClustering:
    """Step A's result for one unit: a label per trajectory, its metrics, the fitted model."""

    labels: np.ndarray
    metrics: dict[str, float]
    model: Any = None
    margins: np.ndarray | None = None  # nats to the next best cluster (``ranking.style_margin``)


@dataclass
class UnitResult:
    """A unit run in-process end to end (:func:`run_unit`)."""

    clustering: UnitClustering
    metrics: dict[str, float]
    tables: dict[str, Any] = field(default_factory=dict)
    stopped: str | None = None  # why ``run_unit``'s ``after_cluster`` stopped it after Step A


def has_styles(unit: Unit) -> bool:
    """Whether every trajectory carries a ground-truth style (used only to score, never to fit)."""
    return bool(len(unit.dataset.styles)) and bool((unit.dataset.styles >= 0).all())


def partial_styles_note(unit: Unit) -> str | None:
    """What a unit whose styles are known for some trajectories only loses (None otherwise):
    style scoring needs every trajectory labelled, so it is left out, which would pass unnoticed."""
    styles = unit.dataset.styles
    unknown = int((styles < 0).sum())
    if not unknown or unknown == len(styles):
        return None
    return (
        f"{unit.name}: {unknown} of {len(styles)} trajectories have style -1 (unknown): the scores "
        f"against the true styles (clustering accuracy, ARI, NMI, the supervised ceiling, the "
        f"corruption study) need every trajectory labelled and are left out"
    )


def cluster_unit(
    unit: Unit, cluster_cfg, seed: int, ceiling: bool = True, confidence: bool = True
) -> UnitClustering:
    """Step A on what the domain says to cluster, with its label-free confidence (refits on
    subsamples, ``clustering.confidence_runs``; skipped without ``confidence``); scored against
    true styles when they exist (and, with ``ceiling``, against what a classifier given those
    styles reaches)."""
    from pcpg_dist.stages.clustering import cluster, clustering_metrics
    from pcpg_dist.stages.clustering.confidence import stability

    result = cluster(unit.clustered, cluster_cfg, seed)
    metrics = {
        f"clustering/{k}": float(v) for k, v in result.metrics.items() if isinstance(v, int | float)
    }
    measured = "clustering/stability" in metrics  # bag_auto chose by it (stages/clustering/select)
    if confidence and not measured and cluster_cfg.confidence_runs > 0 and cluster_cfg.k > 1:
        found = stability(
            unit.clustered,
            cluster_cfg,
            seed,
            result.labels,
            cluster_cfg.confidence_runs,
            cluster_cfg.confidence_fraction,
        )
        metrics.update({f"clustering/{k}": v for k, v in found.items()})
    if has_styles(unit):
        from pcpg_dist.stages.clustering.ceiling import ceiling_panel, gap_to_ceiling

        sup = clustering_metrics(unit.dataset.styles, result.labels)
        metrics.update(
            {f"clustering/{k}": float(v) for k, v in sup.items() if isinstance(v, int | float)}
        )
        # what a classifier given the true styles reaches: the best of a panel (ceiling.py)
        panel = (
            ceiling_panel(unit.dataset, seed=seed, move_features=cluster_cfg.move_features)
            if ceiling and cluster_cfg.ceiling
            else {}
        )
        if panel:
            top = max(panel.values())
            metrics.update({f"clustering/ceiling_{name}": v for name, v in panel.items()})
            metrics["clustering/ceiling"] = top
            metrics["clustering/gap_to_ceiling"] = gap_to_ceiling(
                top, metrics["clustering/accuracy"]
            )
    metrics["clustering/fit_seconds"] = result.fit_seconds
    return UnitClustering(
        np.asarray(result.labels, np.int64), metrics, result.model, result.margins
    )


def plan_unit(
    unit: Unit,
    labels: np.ndarray,
    cfg,
    *,
    rank_cfg=None,
    seeds=None,
    corruption: bool = True,
    margins: np.ndarray | None = None,
    only: list[str] | None = None,
):
    """Step B: every training cell of the unit (PCPG, No Clustering, corrupted labels), ranked by
    the domain's skill score (and the clustering's ``margins`` with ``ranking.style_margin``).
    Corruption cells need true styles to mean anything. ``only``: just the cells of those keys
    (a training task builds its own group's cells)."""
    from pcpg_dist.stages.ranking import plan_cells

    return plan_cells(
        **_plan_args(unit, labels, cfg, rank_cfg, seeds, corruption, margins), only=only
    )


def plan_unit_specs(unit: Unit, labels: np.ndarray, cfg, *, margins: np.ndarray | None = None):
    """The specs of :func:`plan_unit`'s cells, in its order, without their rows: what a runner
    needs to cut a unit into training groups (each group's task builds its cells)."""
    from pcpg_dist.stages.ranking import cell_subsets

    args = _plan_args(unit, labels, cfg, None, None, True, margins)
    return [spec for spec, _ in cell_subsets(**args)]


def _plan_args(unit: Unit, labels, cfg, rank_cfg, seeds, corruption: bool, margins) -> dict:
    corrupt = cfg.evaluation.corruption_levels if corruption and has_styles(unit) else ()
    return {
        "dataset": unit.dataset,
        "labels": labels,
        "train_idx": unit.train_idx,
        "cfg": rank_cfg or cfg.ranking,
        "seeds": cfg.seeds if seeds is None else seeds,
        "k": cfg.clustering.k,
        "score": contract.score(cfg),
        "corruption_levels": corrupt,
        "corruption_ps": cfg.evaluation.corruption_ps,
        "margins": margins,
    }


def evaluate_unit(
    unit: Unit,
    labels: np.ndarray,
    trained,
    cfg,
    out_dir: str | Path | None = None,
    *,
    rank_cfg=None,
    eval_cfg=None,
    rollouts: bool = True,
    extras: bool = True,
    margins: np.ndarray | None = None,
    model=None,
) -> dict[str, float]:
    """Accuracy tables, cross accuracy, rollouts and the domain's extras; finite metrics only.
    ``model``: the fitted clustering, to classify the agents' rollouts."""
    from pcpg_dist.stages.evaluation import evaluate

    result = evaluate(
        unit.dataset,
        labels,
        unit.test_idx,
        trained,
        rank_cfg or cfg.ranking,
        eval_cfg or cfg.evaluation,
        out_dir=out_dir,
        hooks=contract.hooks(cfg, unit.name) if rollouts else None,
        score=contract.score(cfg),
        k=cfg.clustering.k,
        margins=margins,
        model=model,
    )
    metrics = {k: float(v) for k, v in result.metrics.items() if np.isfinite(v)}
    if extras and out_dir is not None:
        metrics.update(contract.extras(cfg, unit, labels, trained, Path(out_dir)))
    return metrics


def run_unit(
    unit: Unit,
    cfg,
    out_dir: str | Path | None = None,
    *,
    ceiling: bool = True,
    confidence: bool = True,
    rank_cfg=None,
    eval_cfg=None,
    seeds=None,
    corruption: bool = True,
    rollouts: bool = True,
    extras: bool = True,
    after_cluster: Callable[[UnitClustering], str | None] | None = None,
) -> UnitResult:
    """The whole chain in this process (a notebook, a test, one tuning trial).

    The keyword options are those of :func:`cluster_unit`, :func:`plan_unit` and
    :func:`evaluate_unit` (a tuning trial skips what its score does not use); ``after_cluster``
    sees Step A's result and may return a reason to stop there (the result's ``stopped``)."""
    from pcpg_dist.stages.bc import train_plan
    from pcpg_dist.stages.clustering.confidence import verdict_of

    clustering = cluster_unit(
        unit, cfg.clustering, cfg.seed, ceiling=ceiling, confidence=confidence
    )
    if after_cluster is not None:
        reason = after_cluster(clustering)
        if reason is not None:
            return UnitResult(clustering, dict(clustering.metrics), stopped=reason)
    cells = plan_unit(
        unit,
        clustering.labels,
        cfg,
        rank_cfg=rank_cfg,
        seeds=seeds,
        corruption=corruption,
        margins=clustering.margins,
    )
    said = verdict_of(clustering.metrics, cfg.clustering.k)
    trained = train_plan(cells, cfg.bc, said.doubts_styles)
    metrics = evaluate_unit(
        unit,
        clustering.labels,
        trained,
        cfg,
        out_dir,
        rank_cfg=rank_cfg,
        eval_cfg=eval_cfg,
        rollouts=rollouts,
        extras=extras,
        margins=clustering.margins,
        model=clustering.model,
    )
    return UnitResult(clustering, {**clustering.metrics, **metrics})
