"""One huge log through the pipeline on ``ray.data``: read, features, k-means, ranking, BC cells
and evaluation over blocks, with the driver holding only reduced statistics.

The stages are :mod:`pcpg_dist.stages.streamed`'s pure block functions; this module only
wires them into the engine. The log is read in blocks (on a cluster, local files on the driver's
node only; every later step runs anywhere, and the object store spills to disk rather than
failing). Per-trajectory features are per-block partial sums merged by a hash aggregation;
the k-means fit, the score ranges and histograms, the evaluation counts are per-block vectors
summed as they stream past. The one table that grows with the log is the trajectory -> code
lookup (16 bytes a trajectory) that tags every step row with its cell; it is assembled in a task
and shared through the object store. The tagged rows are materialised once (spilled to disk
when larger than the store) and every BC group (as few tasks as keep every CPU busy, a few torch
threads each) streams them once an epoch.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pcpg_dist.domains.base import StreamSource
from pcpg_dist.orchestration.streaming.engine import engine_errors, quiet_engine
from pcpg_dist.orchestration.streaming.steps import (
    clustering_quality,
    feature_table,
    fit_kmeans,
    label_table,
    lookup_of,
    tagged_rows,
)
from pcpg_dist.orchestration.streaming.training import train_cells, train_spec
from pcpg_dist.stages.streamed import cells as P
from pcpg_dist.stages.streamed.model import StreamedModel


@dataclass
class StreamOutcome:
    """What a streamed unit produced: metrics as the in-memory pipeline names them, the
    clustering's quality, per-stage seconds, the trained cells and where each came from."""

    metrics: dict[str, float] = field(default_factory=dict)
    clustering: dict[str, float] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    cells: dict[int, list[tuple[int, float]]] = field(default_factory=dict)  # seed -> cells
    weights: dict[int, list[list[np.ndarray]]] = field(default_factory=dict)
    epochs: dict[int, list[int]] = field(default_factory=dict)
    labels: dict[int, Any] = field(default_factory=dict)  # seed -> ray.data labels dataset
    models: dict[int, StreamedModel] = field(default_factory=dict)  # seed -> its k-means
    n_trajectories: int = 0
    steps: int = 0


def accuracies(correct: np.ndarray, rows: np.ndarray, cells, ps) -> dict[str, float]:
    """PCPG (each test row predicted by its cluster's agent) and No Clustering accuracy per p."""
    index = {cell: i for i, cell in enumerate(cells)}
    total = max(rows.sum(), 1.0)
    out = {}
    for pi, p in enumerate(ps):
        own = sum(correct[index[(c, pi)], c] for c in range(correct.shape[1]))
        out[f"pcpg/accuracy/p{p:g}"] = float(own / total)
        out[f"baseline/accuracy/p{p:g}"] = float(correct[index[(P.NC, pi)]].sum() / total)
    return out


def stream_unit(
    source: StreamSource,
    cfg,
    node_cpus: list[int],
    advance: Callable[..., None] = lambda *a, **k: None,
) -> StreamOutcome:
    """Features once, then per seed: k-means, ranking, the tagged rows, every cell, evaluation.
    ``advance`` is told of each finished step (:data:`STEPS_PER_SEED` per seed, 1 for the
    features), with what runs next. ``node_cpus``: the CPUs of each node (how the BC cells are
    split into tasks)."""
    quiet_engine()
    out = StreamOutcome(steps=source.steps)
    k, ps = cfg.clustering.k, tuple(cfg.ranking.ps)
    spec = train_spec(cfg, source)
    cells = [(c, pi) for pi in range(len(ps)) for c in [*range(k), P.NC]]
    clock = _Clock(out.seconds)
    per_seed: list[dict[str, float]] = []
    with engine_errors():
        with clock("features"):
            feats, smean, sscale = feature_table(source)
            out.n_trajectories = feats.count()
        advance(1, description=f"Streamed: k-means (seed {cfg.seeds[0]})")
        for i, seed in enumerate(cfg.seeds):
            with clock("cluster"):
                mean, scale, centres, iterations = fit_kmeans(feats, k, seed)
            out.models[seed] = StreamedModel(
                seed=seed,
                states=list(source.states),
                n_actions=source.n_actions,
                mean=mean.tolist(),
                scale=scale.tolist(),
                centres=centres.tolist(),
            )
            advance(1, description="Streamed: ranking")
            with clock("rank"):
                labels, contingency = label_table(feats, mean, scale, centres, seed, cfg, source)
            quality = clustering_quality(contingency)
            advance(1, description="Streamed: tagging steps")
            lookup = lookup_of(labels)
            with clock("tag"):  # the training rows, once; each epoch streams them again
                rows = tagged_rows(source, lookup, smean, sscale, test=False)
                rows = rows.randomize_block_order(seed=seed).materialize()
            advance(1, description="Streamed: held-out steps")
            with clock("evaluate"):  # the held-out rows, once; the BC tasks score their cells
                held_out = tagged_rows(source, lookup, smean, sscale, test=True).materialize()
            advance(1, description="Streamed: BC cells (and their held-out accuracy)")
            with clock("train"):
                groups = train_cells(rows, held_out, cells, spec, seed, k, node_cpus)
            scoring = max(g["evaluate_s"] for g in groups)  # the tasks' scoring, timed inside
            out.seconds["train"] -= scoring
            out.seconds["evaluate"] += scoring
            order = {cell: (g, i) for g in groups for i, cell in enumerate(g["cells"])}
            states = [order[c][0]["states"][order[c][1]] for c in cells]
            correct = np.stack([order[c][0]["correct"][order[c][1]] for c in cells])
            test_rows = groups[0]["test_rows"]
            del rows, held_out, lookup
            later = cfg.seeds[i + 1 :]
            advance(1, description=f"Streamed: k-means (seed {later[0]})" if later else "Streamed")
            per_seed.append(
                {
                    **accuracies(correct, test_rows, cells, ps),
                    **quality,
                    "clustering/iterations": float(iterations),
                }
            )
            out.cells[seed], out.weights[seed] = cells, states
            out.epochs[seed] = [g["epochs"] for g in groups]
            out.labels[seed] = labels.select_columns(["trajectory", "test", "cluster", "code"])
    merged = {key: float(np.mean([m[key] for m in per_seed])) for key in per_seed[0]}
    out.clustering = {m: v for m, v in merged.items() if m.startswith("clustering/")}
    out.metrics = {m: v for m, v in merged.items() if not m.startswith("clustering/")}
    out.metrics["bc/epochs_max"] = float(max(max(e) for e in out.epochs.values()))
    return out


STEPS_PER_SEED = 5  # k-means, ranking, tagging, held-out rows, BC and its scoring


class _Clock:
    """``with clock(stage):`` adds the block's wall time to ``seconds[stage]``."""

    def __init__(self, seconds: dict[str, float]) -> None:
        self.seconds = seconds

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + time.perf_counter() - t0
