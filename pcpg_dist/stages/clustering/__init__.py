"""Step A: cluster trajectories by play-style (:func:`cluster`), score a clustering
(:func:`clustering_metrics`) and read a saved model back (:func:`load_model`).

The package's modules, by concern: :mod:`.step` (the dispatch over the table of clusterers in
:mod:`pcpg_dist.config.clusterers`; one fit), :mod:`.select` (``cluster``: ``bag_auto``'s choice
between two fits by stability), :mod:`.auto` (which method runs on a dataset, whether it trains
a network), one module per clusterer family (:mod:`.kmeans`, :mod:`.bags`,
:mod:`.greedy_mix` with :mod:`.greedy_likelihood`, :mod:`.lstm` with :mod:`.autoencoder`,
:mod:`.policy_mix` with :mod:`.policy_network`, :mod:`.choice_mix` with :mod:`.move_pairs`,
:mod:`.move_features` and :mod:`.style_weights`), the shared inputs (:mod:`.states`,
:mod:`.features`), the fitted model (:mod:`.model`, :mod:`.model_io`), :mod:`.metrics` and the
supervised :mod:`.ceiling`.

The names below are imported on first use, so importing this package (as `pcpg --help` and
loading a config do) imports no torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from pcpg_dist.config.clustering import ClusterConfig

if TYPE_CHECKING:
    from pcpg_dist.stages.clustering.auto import falls_back, needs_network
    from pcpg_dist.stages.clustering.metrics import (
        cluster_sizes,
        clustering_metrics,
        hungarian_mapping,
    )
    from pcpg_dist.stages.clustering.model import ClusterModel
    from pcpg_dist.stages.clustering.model_io import load_model
    from pcpg_dist.stages.clustering.policy_mix import counter_summary, monotone_features
    from pcpg_dist.stages.clustering.select import cluster
    from pcpg_dist.stages.clustering.states import checked_sequences
    from pcpg_dist.stages.clustering.step import Clustering

#: public name -> the module of this package that defines it
_EXPORTS = {
    "Clustering": "step",
    "cluster": "select",
    "ClusterModel": "model",
    "load_model": "model_io",
    "clustering_metrics": "metrics",
    "cluster_sizes": "metrics",
    "hungarian_mapping": "metrics",
    "falls_back": "auto",
    "needs_network": "auto",
    "checked_sequences": "states",
    "counter_summary": "policy_mix",
    "monotone_features": "policy_mix",
}

__all__ = [
    "ClusterConfig",
    "ClusterModel",
    "Clustering",
    "checked_sequences",
    "cluster",
    "cluster_sizes",
    "clustering_metrics",
    "counter_summary",
    "falls_back",
    "hungarian_mapping",
    "load_model",
    "monotone_features",
    "needs_network",
]


def __getattr__(name: str) -> Any:
    """Import the module that defines ``name`` on first use (PEP 562)."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value
