"""Step A: cluster trajectories by play-style, and score a clustering.

``cluster(dataset, cfg, seed)`` is a pure function: it never looks at ``dataset.styles``; true
styles only score the result afterwards through :func:`clustering_metrics`.

Methods (one interface, one row each in :data:`pcpg_dist.config.clusterers.CLUSTERERS`, so the LSTM model's value is measured, not assumed):

- ``lstm_dec`` — the paper's model: an LSTM sequence autoencoder pretrained on reconstruction,
  then trained on reconstruction + ``cluster_weight`` x a DEC clustering loss (Student-t soft
  assignment to k centroids, KL divergence to the sharpened target distribution; centroids start
  at k-means of the pretrained latents; Xie et al. 2016, with the reconstruction term of IDEC).
- ``lstm_kmeans`` — k-means on the pretrained latents only (what DEC adds over this is measured).
- ``summary_kmeans`` — k-means on [length, final state, mean state] per trajectory.
- ``visits_kmeans`` — k-means (cosine) on which distinct states a trajectory visits.
- ``bag_kmeans`` — weighted k-means (cosine) on distinct visitation rows: visited states,
  state-actions and the final state (pcpg_dist/stages/clustering/features.py), duplicates as weights.
- ``bag_mop`` — a mixture of k policies pi_c(a | s) fitted by EM from bag_kmeans' labels.
- ``greedy_mix`` — a mixture of k greedy policies with one uniform noise level, fitted by
  coordinate ascent from bag_kmeans' labels (pcpg_dist/stages/clustering/greedy_mix.py): style = which action.
- ``bag_auto`` (the default) — on discrete states greedy_mix, or policy_mix where its fit is
  clearly the more stable under resampling (:mod:`.select`); policy_mix on continuous states
  (where a state is almost never seen twice, a per-state policy says nothing; lstm_dec where the
  log holds one action throughout, so only the states can show a style).
- ``policy_mix`` — a mixture of k neural policies pi_c(a | s) (shared trunk, k heads) fitted by
  hard EM over whole trajectories, started from k-means on the gain and mean of the features that
  never decrease within a trajectory (counters); for continuous states (MiniDungeons).

Determinism: all randomness comes from ``seed`` (a local ``torch.Generator`` and k-means'
``random_state``); with the same data, seed and torch thread count the labels are identical.
"""

from __future__ import annotations

import importlib
import time
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from pcpg_dist.common.errors import DataError
from pcpg_dist.config.clusterers import CLUSTERERS
from pcpg_dist.config.clustering import ClusterConfig
from pcpg_dist.stages.clustering.auto import resolve_method
from pcpg_dist.stages.clustering.metrics import (
    cluster_sizes,
    label_free_metrics,
    sample_distances,
    silhouette_precomputed,
)
from pcpg_dist.stages.clustering.model import ClusterModel, Fitted
from pcpg_dist.stages.clustering.states import checked_sequences


@dataclass(frozen=True)
class Clustering:
    """Result of :func:`cluster`: labels 0..k-1 per trajectory and label-free diagnostics."""

    labels: np.ndarray  # (n_traj,) int64
    latents: np.ndarray | None  # (n_traj, latent) the space the clusters live in
    metrics: dict[str, float]  # label-free only: silhouette, size fractions, losses
    model: ClusterModel | None
    fit_seconds: float
    #: (n_traj,) how many nats more likely each trajectory is under its own cluster than under the
    #: next best; from the clusterers with a likelihood (greedy_mix, bag_auto on discrete states,
    #: policy_mix), None from the others. Step B's ``ranking.style_margin`` reads it.
    margins: np.ndarray | None = None

    @property
    def sizes(self) -> np.ndarray:
        """Trajectories per cluster, length k (empty clusters count 0)."""
        k = self.model.k if self.model is not None else int(self.labels.max(initial=-1)) + 1
        return cluster_sizes(self.labels, k)


def fitting_function(method: str):
    """The fitting function of ``method``: its table entry's ``"module:function"`` target,
    imported only now (so a method's heavy imports load only where it runs)."""
    module, _, function = CLUSTERERS[method].fit.partition(":")
    return getattr(importlib.import_module(module), function)


def cluster_once(dataset, cfg: ClusterConfig, seed: int) -> Clustering:
    """One fit of ``cfg.method`` (or its continuous-state fallback): ``dataset``'s trajectories in
    ``cfg.k`` play-styles; never reads ``dataset.styles``. :func:`.select.cluster` (the package's
    ``cluster``) may fit two methods and keep one.

    Raises :class:`DataError` for an empty dataset, non-finite states, or fewer trajectories than k.
    Call :func:`pcpg_dist.common.devices.set_threads` first: same data + seed + threads = same labels.
    """
    start = time.perf_counter()
    states, offsets = checked_sequences(dataset)
    n = len(offsets) - 1
    if n < cfg.k:
        raise DataError(
            f"clustering: {n} trajectories in {dataset.domain}-{dataset.env}, "
            f"fewer than k={cfg.k} clusters: set clustering.k to at most {n}"
        )
    metrics: dict[str, float] = {}
    cfg = resolve_method(cfg, dataset, states, metrics)
    fitted: Fitted = fitting_function(cfg.method)(dataset, states, offsets, cfg, seed, metrics)
    latents = fitted.latents
    labels = fitted.labels if fitted.labels is not None else fitted.model.assign(latents)
    if fitted.silhouette and sparse.issparse(latents) and "silhouette" not in metrics:
        idx, dist = sample_distances(latents, cfg.silhouette_sample, seed)
        s = silhouette_precomputed(dist, labels[idx])
        if s is not None:
            metrics["silhouette"] = s
    sample = cfg.silhouette_sample if fitted.silhouette else 0
    metrics.update(label_free_metrics(latents, labels, cfg.k, sample, seed))
    return Clustering(
        labels=labels,
        latents=latents,
        metrics=metrics,
        model=fitted.model,
        fit_seconds=time.perf_counter() - start,
        margins=fitted.margins,
    )
