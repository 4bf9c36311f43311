"""The k-means clusterers of Step A: ``summary_kmeans`` (length, final and mean state) and
``visits_kmeans`` (which distinct states a trajectory visits), and the k-means centroids the LSTM
methods start from."""

from __future__ import annotations

import numpy as np
from sklearn.cluster import KMeans

from pcpg_dist.config.clustering import ClusterConfig
from pcpg_dist.stages.clustering.model import ClusterModel, Fitted
from pcpg_dist.stages.clustering.states import (
    fit_normaliser,
    state_vocabulary,
    summary_features,
    visit_features,
)


def kmeans_centroids(x: np.ndarray, k: int, seed: int, n_init: int) -> np.ndarray:
    km = KMeans(n_clusters=k, n_init=n_init, random_state=seed).fit(x.astype(np.float64))
    return km.cluster_centers_.astype(np.float32)


def fit_summary(
    dataset, states: np.ndarray, offsets: np.ndarray, cfg: ClusterConfig, seed: int, metrics: dict
) -> Fitted:
    """summary_kmeans: k-means on the standardised [length, final state, mean state]."""
    feats = summary_features(states, offsets)
    mean, std = fit_normaliser(feats)
    norm = ((feats - mean) / std).astype(np.float32)
    centroids = kmeans_centroids(norm, cfg.k, seed, cfg.kmeans_n_init)
    model = ClusterModel(
        cfg.method,
        cfg.model_dump(),
        states.shape[1],
        mean,
        std,
        centroids,
        None,
        tuple(dataset.feature_names),
    )
    return Fitted(None, norm, model)


def fit_visits(
    dataset, states: np.ndarray, offsets: np.ndarray, cfg: ClusterConfig, seed: int, metrics: dict
) -> Fitted:
    """visits_kmeans: k-means (cosine) on which vocabulary states each trajectory visits."""
    vocab = state_vocabulary(states)
    latents = visit_features(states, offsets, vocab)
    km = KMeans(n_clusters=cfg.k, n_init=cfg.kmeans_n_init, random_state=seed).fit(latents)
    d = states.shape[1]
    model = ClusterModel(
        cfg.method,
        cfg.model_dump(),
        d,
        np.zeros(d),
        np.ones(d),
        km.cluster_centers_,
        None,
        tuple(dataset.feature_names),
        vocab,
    )
    return Fitted(None, latents, model)
