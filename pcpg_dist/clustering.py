"""Step A: cluster trajectories by play-style, and score a clustering.

``cluster(dataset, cfg, seed)`` is a pure function: it never looks at ``dataset.styles``; true
styles only score the result afterwards through :func:`clustering_metrics`.

Methods (one interface, so the LSTM model's value is measured, not assumed):

- ``lstm_dec`` — the paper's model: an LSTM sequence autoencoder pretrained on reconstruction,
  then trained on reconstruction + ``cluster_weight`` x a DEC clustering loss (Student-t soft
  assignment to k centroids, KL divergence to the sharpened target distribution; centroids start
  at k-means of the pretrained latents; Xie et al. 2016, with the reconstruction term of IDEC).
- ``lstm_kmeans`` — k-means on the pretrained latents only (what DEC adds over this is measured).
- ``summary_kmeans`` — k-means on [length, final state, mean state] per trajectory.

Determinism: all randomness comes from ``seed`` (a local ``torch.Generator`` and k-means'
``random_state``); with the same data, seed and torch thread count the labels are identical.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment
from sklearn.cluster import KMeans
from sklearn.metrics import adjusted_rand_score, normalized_mutual_info_score, silhouette_score

from pcpg_dist.cluster_models import (
    ClusterModel,
    SequenceAutoencoder,
    checked_sequences,
    encode_all,
    fit_normaliser,
    load_model,
    make_batches,
    state_vocabulary,
    summary_features,
    visit_features,
)
from pcpg_dist.config.stages import ClusterConfig
from pcpg_dist.errors import DataError

__all__ = [
    "ClusterConfig",
    "Clustering",
    "ClusterModel",
    "cluster",
    "clustering_metrics",
    "cluster_sizes",
    "hungarian_mapping",
    "load_model",
]


@dataclass(frozen=True)
class Clustering:
    """Result of :func:`cluster`: labels 0..k-1 per trajectory and label-free diagnostics."""

    labels: np.ndarray  # (n_traj,) int64
    latents: np.ndarray | None  # (n_traj, latent) the space the clusters live in
    metrics: dict[str, float]  # label-free only: silhouette, size fractions, losses
    model: ClusterModel | None
    fit_seconds: float

    @property
    def sizes(self) -> np.ndarray:
        """Trajectories per cluster, length k (empty clusters count 0)."""
        k = self.model.k if self.model is not None else int(self.labels.max(initial=-1)) + 1
        return cluster_sizes(self.labels, k)


# --------------------------------------------------------------------- fitting
def _kmeans(x: np.ndarray, k: int, seed: int, n_init: int) -> np.ndarray:
    km = KMeans(n_clusters=k, n_init=n_init, random_state=seed).fit(x.astype(np.float64))
    return km.cluster_centers_.astype(np.float32)


def _student_t(z: torch.Tensor, mu: torch.Tensor, alpha: float) -> torch.Tensor:
    """DEC's soft assignment q_ij ~ (1 + |z_i - mu_j|^2 / alpha)^(-(alpha+1)/2), rows sum to 1."""
    d2 = torch.cdist(z, mu).pow(2)
    q = (1.0 + d2 / alpha).pow(-(alpha + 1.0) / 2.0)
    return q / q.sum(dim=1, keepdim=True)


def _target(q: torch.Tensor) -> torch.Tensor:
    """DEC's sharpened target p_ij ~ q_ij^2 / f_j (f_j = soft cluster size), rows sum to 1."""
    w = q.pow(2) / q.sum(dim=0)
    return w / w.sum(dim=1, keepdim=True)


def _fit_lstm(
    states: np.ndarray,
    offsets: np.ndarray,
    cfg: ClusterConfig,
    seed: int,
    metrics: dict[str, float],
) -> tuple[SequenceAutoencoder, np.ndarray, np.ndarray, np.ndarray]:
    """Pretrain the autoencoder, init centroids by k-means, and (lstm_dec) run joint DEC training.

    Returns the autoencoder, normaliser (mean, std) and centroids.
    """
    n = len(offsets) - 1
    mean, std = fit_normaliser(states)
    batches = make_batches((states - mean) / std, offsets, cfg.batch_size)
    gen = torch.Generator().manual_seed(seed)
    ae = SequenceAutoencoder(states.shape[1], cfg.hidden_size, cfg.latent_size, cfg.pooling)
    ae.reset_parameters(gen)
    opt = torch.optim.Adam(ae.parameters(), lr=cfg.lr)
    mse = torch.nn.functional.mse_loss

    recon = float("nan")
    for _ in range(cfg.pretrain_epochs):
        total, rows = 0.0, 0
        for bi in torch.randperm(len(batches), generator=gen).tolist():
            b = batches[bi]
            loss = mse(ae.decode(ae.encode(b.packed, b), b), b.packed.data)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total += loss.item() * len(b.packed.data)
            rows += len(b.packed.data)
        recon = total / rows
    metrics["pretrain_recon_mse"] = recon

    ae.eval()
    z = encode_all(ae, batches, n)
    centroids = _kmeans(z.numpy(), cfg.k, seed, cfg.kmeans_n_init)
    if cfg.method != "lstm_dec" or cfg.dec_epochs == 0:
        return ae, mean, std, centroids

    ae.train()
    mu = torch.nn.Parameter(torch.from_numpy(centroids.copy()))
    opt = torch.optim.Adam([*ae.parameters(), mu], lr=cfg.lr)
    labels = torch.empty(0, dtype=torch.long)
    epochs_run = 0
    for epoch in range(cfg.dec_epochs):
        # One pass gives both the new target and the stopping test (as in DEC): the labels of the
        # weights at the start of this epoch against those at the start of the previous one.
        with torch.no_grad():
            q_all = _student_t(encode_all(ae, batches, n), mu, cfg.alpha)
        new = q_all.argmax(1)
        if epoch > 0 and float((new != labels).float().mean()) < cfg.dec_tol:
            break
        labels, p_all = new, _target(q_all)
        total_r, total_c = 0.0, 0.0
        for bi in torch.randperm(len(batches), generator=gen).tolist():
            b = batches[bi]
            zb = ae.encode(b.packed, b)
            r_loss = mse(ae.decode(zb, b), b.packed.data)
            q = _student_t(zb, mu, cfg.alpha)
            p = p_all[b.index]
            c_loss = (p * (torch.log(p + 1e-12) - torch.log(q + 1e-12))).sum(1).mean()
            loss = r_loss + cfg.cluster_weight * c_loss
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total_r += r_loss.item() * len(b.index)
            total_c += c_loss.item() * len(b.index)
        epochs_run += 1
        metrics["dec_recon_mse"], metrics["dec_kl"] = total_r / n, total_c / n
    metrics["dec_epochs_run"] = float(epochs_run)
    return ae, mean, std, mu.detach().numpy().copy()


def cluster(dataset, cfg: ClusterConfig, seed: int) -> Clustering:
    """Cluster ``dataset``'s trajectories into ``cfg.k`` play-styles; never reads ``dataset.styles``.

    Raises :class:`DataError` for an empty dataset, non-finite states, or fewer trajectories than k.
    Call :func:`pcpg_dist.parallel.set_threads` first: same data + seed + threads = same labels.
    """
    start = time.perf_counter()
    states, offsets = checked_sequences(dataset)
    n = len(offsets) - 1
    if n < cfg.k:
        raise DataError(
            f"clustering: {n} trajectories in {dataset.domain}-{dataset.env}, "
            f"fewer than k={cfg.k} clusters"
        )
    metrics: dict[str, float] = {}
    config = cfg.model_dump()
    if cfg.method == "visits_kmeans":
        vocab = state_vocabulary(states)
        latents = visit_features(states, offsets, vocab)
        km = KMeans(n_clusters=cfg.k, n_init=cfg.kmeans_n_init, random_state=seed).fit(latents)
        d = states.shape[1]
        model = ClusterModel(cfg.method, config, d, np.zeros(d), np.ones(d), km.cluster_centers_, None,
                             tuple(dataset.feature_names), vocab)
    elif cfg.method == "summary_kmeans":
        feats = summary_features(states, offsets)
        mean, std = fit_normaliser(feats)
        norm = ((feats - mean) / std).astype(np.float32)
        centroids = _kmeans(norm, cfg.k, seed, cfg.kmeans_n_init)
        model = ClusterModel(
            cfg.method,
            config,
            states.shape[1],
            mean,
            std,
            centroids,
            None,
            tuple(dataset.feature_names),
        )
        latents = norm
    else:
        # Torch's global RNG is untouched (local generator); fork it anyway so nothing inside
        # torch that might draw from it (e.g. a future dropout) leaks state to the caller.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            ae, mean, std, centroids = _fit_lstm(states, offsets, cfg, seed, metrics)
        model = ClusterModel(
            cfg.method,
            config,
            states.shape[1],
            mean,
            std,
            centroids,
            ae,
            tuple(dataset.feature_names),
        )
        latents = model.features(dataset)
    labels = model.assign(latents)
    metrics.update(_label_free_metrics(latents, labels, cfg.k, cfg.silhouette_sample, seed))
    return Clustering(
        labels=labels,
        latents=latents,
        metrics=metrics,
        model=model,
        fit_seconds=time.perf_counter() - start,
    )


# --------------------------------------------------------------------- metrics
def cluster_sizes(pred: np.ndarray, k: int) -> np.ndarray:
    """Trajectories per cluster 0..k-1."""
    return (
        np.bincount(np.asarray(pred, np.int64), minlength=k)[: max(k, 0)]
        if len(pred)
        else np.zeros(k, np.int64)
    )


def _label_free_metrics(
    latents: np.ndarray, labels: np.ndarray, k: int, sample: int, seed: int
) -> dict[str, float]:
    sizes = cluster_sizes(labels, k)
    out = {
        "n_clusters_used": float((sizes > 0).sum()),
        "size_min_frac": float(sizes.min() / len(labels)),
        "size_max_frac": float(sizes.max() / len(labels)),
    }
    if 2 <= out["n_clusters_used"] < len(labels):
        out["silhouette"] = float(
            silhouette_score(
                latents, labels, sample_size=min(sample, len(labels)), random_state=seed
            )
        )
    return out


def _contingency(true: np.ndarray, pred: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t_vals, t_idx = np.unique(true, return_inverse=True)
    p_vals, p_idx = np.unique(pred, return_inverse=True)
    table = np.zeros((len(p_vals), len(t_vals)), np.int64)
    np.add.at(table, (p_idx, t_idx), 1)
    return table, p_vals, t_vals


def _check_pair(true: np.ndarray, pred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    true, pred = np.asarray(true).ravel(), np.asarray(pred).ravel()
    if true.shape != pred.shape:
        raise DataError(
            f"true labels ({true.shape[0]}) and predicted labels ({pred.shape[0]}) differ in length"
        )
    if true.size == 0:
        raise DataError("cannot score a clustering of zero trajectories")
    return true, pred


def hungarian_mapping(true: np.ndarray, pred: np.ndarray) -> dict[int, int]:
    """Predicted cluster -> true style, one-to-one, maximising matched trajectories.

    With more clusters than styles the unmatched clusters map to -1 ("unknown", as in
    ``Dataset.styles``), so ``accuracy`` computed through the mapping equals Hungarian accuracy.
    """
    true, pred = _check_pair(true, pred)
    table, p_vals, t_vals = _contingency(true, pred)
    rows, cols = linear_sum_assignment(-table)
    mapping = {int(p): -1 for p in p_vals}
    mapping.update({int(p_vals[r]): int(t_vals[c]) for r, c in zip(rows, cols, strict=True)})
    return mapping


def clustering_metrics(
    true: np.ndarray, pred: np.ndarray, latents: np.ndarray | None = None
) -> dict[str, float]:
    """ARI, NMI and Hungarian-matched accuracy against true styles; silhouette when latents given."""
    true, pred = _check_pair(true, pred)
    mapping = hungarian_mapping(true, pred)
    mapped = np.array([mapping[int(p)] for p in pred])
    out = {
        "ari": float(adjusted_rand_score(true, pred)),
        "nmi": float(normalized_mutual_info_score(true, pred)),
        "accuracy": float((mapped == true).mean()),
    }
    if latents is not None and 2 <= len(np.unique(pred)) < len(pred):
        out["silhouette"] = float(
            silhouette_score(latents, pred, sample_size=min(4000, len(pred)), random_state=0)
        )
    return out
