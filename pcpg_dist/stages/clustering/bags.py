"""The bag clusterers of Step A on visitation rows (:mod:`.features`): ``bag_kmeans`` (weighted
k-means, cosine), ``bag_mop`` (a free mixture of policies by EM) and ``greedy_mix`` / ``bag_auto``
on discrete states (a mixture of greedy policies, :mod:`.greedy_mix`), each started from k-means.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.special import logsumexp
from sklearn.cluster import KMeans
from sklearn.preprocessing import normalize

from pcpg_dist.config.clusterers import CLUSTERERS
from pcpg_dist.config.clustering import ClusterConfig
from pcpg_dist.stages.clustering import greedy_mix
from pcpg_dist.stages.clustering.features import bag_matrix, dedup_rows, fit_vocabulary
from pcpg_dist.stages.clustering.metrics import (
    likelihood_margins,
    sample_distances,
    silhouette_precomputed,
)
from pcpg_dist.stages.clustering.model import ClusterModel, Fitted


def _mixture_of_policies(
    x: sparse.csr_matrix,
    w: np.ndarray,
    vocab,
    init: np.ndarray,
    k: int,
    max_iter: int = 100,
    smoothing: float = 0.5,
    tol: float = 1e-7,
) -> np.ndarray:
    """EM for k policies pi_c(a | s) over the state-action columns of distinct bag rows ``x``
    (weights ``w``), started from hard labels ``init``; returns the final hard labels.

    A trajectory's log-likelihood under policy c is sum over its (s, a) of log pi_c(a | s): the
    generative story of PBTG-like data (each style = one noisy policy).
    """
    v = len(vocab.states)
    sa = x[:, v : v + len(vocab.sa_keys)].tocsr()
    sa.data = (sa.data > 0).astype(np.float64)  # counts of the binary pairs, not the cosine scale
    state_of = vocab.sa_keys // vocab.n_actions
    _, state_of = np.unique(state_of, return_inverse=True)
    resp = np.eye(k)[init]
    prev = -np.inf
    for _ in range(max_iter):
        wr = resp * w[:, None]
        cnt = np.asarray(sa.T @ wr) + smoothing  # (P, k)
        tot = np.zeros((state_of.max(initial=-1) + 1, k))
        np.add.at(tot, state_of, cnt)
        logpi = np.log(cnt) - np.log(tot[state_of])
        prior = wr.sum(0) + 1e-9
        loglik = np.asarray(sa @ logpi) + np.log(prior / prior.sum())
        norm = logsumexp(loglik, axis=1)
        resp = np.exp(loglik - norm[:, None])
        total = float((w * norm).sum())
        if total - prev <= tol * abs(total):
            break
        prev = total
    return resp.argmax(1)


def _weighted_means(x, w: np.ndarray, labels: np.ndarray, k: int) -> np.ndarray:
    """(k, width) weighted mean row of each cluster (zeros for an empty cluster)."""
    onehot = sparse.csr_matrix((w, (labels, np.arange(len(labels)))), shape=(k, len(labels)))
    sums = np.asarray((onehot @ x).todense())
    return sums / np.maximum(np.asarray(onehot.sum(axis=1)), 1e-12)


def _greedy_starts(
    xu: sparse.csr_matrix,
    w: np.ndarray,
    inv: np.ndarray,
    first_labels: np.ndarray,
    k: int,
    cfg: ClusterConfig,
    seed: int,
) -> list[np.ndarray]:
    """The starts of greedy_mix: k-means with k, k + 1 and k + 2 clusters, from three seeds
    (greedy_mix.py says why); the first is the k-means with k clusters already fitted."""
    return [first_labels] + [
        KMeans(n_clusters=kk, n_init=cfg.kmeans_n_init, random_state=seed + r)
        .fit(xu, sample_weight=w)
        .labels_[inv]
        for r in range(3)
        for kk in (k, k + 1, k + 2)
        if kk <= xu.shape[0] and (r, kk) != (0, k)
    ]


def _fit_greedy(
    dataset,
    states: np.ndarray,
    vocab,
    starts: list[np.ndarray],
    cfg: ClusterConfig,
    seed: int,
    metrics: dict[str, float],
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, float], np.ndarray]:
    """greedy_mix / bag_auto: ``(labels, (votes, log shares, noise), likelihood margins)``."""
    steps = greedy_mix.Steps.of_dataset(dataset, states, vocab.states)
    fit = greedy_mix.fit(steps, starts, cfg.k, seed=seed)
    labels, greedy = fit.labels, (fit.votes, fit.log_share, fit.noise)
    margins = likelihood_margins(greedy_mix.fit_scores(steps, fit), labels)
    metrics.update(
        {
            "em_rounds": float(fit.sweeps),
            "greedy_mix_moved": fit.moved,
            "greedy_mix_noise": fit.noise,
            "greedy_mix_noise_start": fit.noise_start,
            "greedy_mix_start_clusters": float(fit.start_clusters),
            "greedy_mix_split_merges": float(fit.split_merges),
            "greedy_mix_loglik_per_step": fit.log_likelihood / max(steps.counts.sum(), 1.0),
        }
    )
    return labels, greedy, margins


def fit_bags(
    dataset,
    states: np.ndarray,
    offsets: np.ndarray,
    cfg: ClusterConfig,
    seed: int,
    metrics: dict[str, float],
) -> Fitted:
    """bag_kmeans / bag_mop / greedy_mix / bag_auto on visitation rows.

    Every one starts from weighted k-means on the distinct bag rows; bag_mop refines that by a
    free mixture of policies, greedy_mix and bag_auto by a mixture of greedy policies with
    uniform noise (pcpg_dist/stages/clustering/greedy_mix.py).
    """
    actions = np.asarray(dataset.actions, np.int64)
    vocab = fit_vocabulary(states, actions, int(dataset.n_actions))
    x = normalize(bag_matrix(states, offsets, actions, vocab))
    first, w, inv = dedup_rows(x)
    xu = x[first]
    metrics["distinct_trajectories"] = float(len(first))
    k = min(cfg.k, len(first))
    km = KMeans(n_clusters=k, n_init=cfg.kmeans_n_init, random_state=seed).fit(xu, sample_weight=w)
    greedy = margins = None
    if cfg.method == "bag_mop" and len(vocab.sa_keys):
        labels = _mixture_of_policies(xu, w, vocab, km.labels_, k)[inv]
    elif CLUSTERERS[cfg.method].model == "greedy":
        starts = _greedy_starts(xu, w, inv, km.labels_[inv], k, cfg, seed)
        labels, greedy, margins = _fit_greedy(dataset, states, vocab, starts, cfg, seed, metrics)
    else:
        labels = km.labels_[inv]
    idx, dist = sample_distances(x, cfg.silhouette_sample, seed, first[inv])
    s = silhouette_precomputed(dist, labels[idx])
    if s is not None:
        metrics["silhouette"] = s
    centroids = _weighted_means(x, np.ones(len(labels)), labels, cfg.k)
    d = states.shape[1]
    model = ClusterModel(
        cfg.method,
        cfg.model_dump(),
        d,
        np.zeros(d),
        np.ones(d),
        centroids,
        None,
        tuple(dataset.feature_names),
        None,
        vocab,
        greedy=greedy,
    )
    return Fitted(labels.astype(np.int64), x, model, margins)
