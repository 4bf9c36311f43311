"""The LSTM clusterers of Step A: ``lstm_dec`` (the paper: autoencoder + DEC loss) and
``lstm_kmeans`` (k-means on the pretrained latents).

The autoencoder is pretrained on reconstruction; k-means of its latents gives the centroids;
lstm_dec then trains on reconstruction + ``cluster_weight`` x DEC's clustering loss (Student-t soft
assignment to k centroids, KL divergence to the sharpened target distribution; Xie et al. 2016,
with the reconstruction term of IDEC).
"""

from __future__ import annotations

import numpy as np
import torch

from pcpg_dist.common.devices import resolve_device
from pcpg_dist.config.clustering import ClusterConfig
from pcpg_dist.stages.clustering.autoencoder import (
    PackedBatch,
    SequenceAutoencoder,
    batches_to,
    encode_all,
    make_batches,
)
from pcpg_dist.stages.clustering.kmeans import kmeans_centroids
from pcpg_dist.stages.clustering.model import ClusterModel, Fitted
from pcpg_dist.stages.clustering.states import fit_normaliser


def _student_t(z: torch.Tensor, mu: torch.Tensor, alpha: float) -> torch.Tensor:
    """DEC's soft assignment q_ij ~ (1 + |z_i - mu_j|^2 / alpha)^(-(alpha+1)/2), rows sum to 1."""
    d2 = torch.cdist(z, mu).pow(2)
    q = (1.0 + d2 / alpha).pow(-(alpha + 1.0) / 2.0)
    return q / q.sum(dim=1, keepdim=True)


def _target(q: torch.Tensor) -> torch.Tensor:
    """DEC's sharpened target p_ij ~ q_ij^2 / f_j (f_j = soft cluster size), rows sum to 1."""
    w = q.pow(2) / q.sum(dim=0)
    return w / w.sum(dim=1, keepdim=True)


def _pretrain(
    ae: SequenceAutoencoder,
    batches: list[PackedBatch],
    cfg: ClusterConfig,
    gen: torch.Generator,
    metrics: dict[str, float],
) -> None:
    """Train ``ae`` on reconstruction alone for ``pretrain_epochs`` (fewer once an epoch lowers
    the MSE by less than ``pretrain_tol``); batches in an order drawn from ``gen``."""
    opt = torch.optim.Adam(ae.parameters(), lr=cfg.lr)
    mse = torch.nn.functional.mse_loss
    recon, epochs_run = float("nan"), 0
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
        last, recon = recon, total / rows
        epochs_run += 1
        if cfg.pretrain_tol > 0 and last == last and last - recon < cfg.pretrain_tol * last:
            break  # converged: another epoch would not change the latent space much
    metrics["pretrain_recon_mse"] = recon
    metrics["pretrain_epochs_run"] = float(epochs_run)


def _dec_epoch(
    ae: SequenceAutoencoder,
    batches: list[PackedBatch],
    mu: torch.nn.Parameter,
    p_all: torch.Tensor,
    opt: torch.optim.Optimizer,
    cfg: ClusterConfig,
    gen: torch.Generator,
) -> tuple[float, float]:
    """One epoch on reconstruction + ``cluster_weight`` x KL(p || q) towards the target
    ``p_all``; returns the summed (reconstruction, KL) losses over the trajectories."""
    mse = torch.nn.functional.mse_loss
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
    return total_r, total_c


def _dec_train(
    ae: SequenceAutoencoder,
    batches: list[PackedBatch],
    n: int,
    centroids: np.ndarray,
    cfg: ClusterConfig,
    gen: torch.Generator,
    device: torch.device,
    metrics: dict[str, float],
) -> np.ndarray:
    """DEC: train the autoencoder and the centroids (started at ``centroids``; ``n`` trajectories) jointly until
    fewer than ``dec_tol`` of the labels change in an epoch; returns the final centroids."""
    ae.train()
    mu = torch.nn.Parameter(torch.from_numpy(centroids.copy()).to(device))
    opt = torch.optim.Adam([*ae.parameters(), mu], lr=cfg.lr)
    labels = torch.empty(0, dtype=torch.long, device=device)
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
        total_r, total_c = _dec_epoch(ae, batches, mu, p_all, opt, cfg, gen)
        epochs_run += 1
        metrics["dec_recon_mse"], metrics["dec_kl"] = total_r / n, total_c / n
    metrics["dec_epochs_run"] = float(epochs_run)
    return mu.detach().cpu().numpy().copy()


def _train_lstm(
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
    device = resolve_device(cfg.device, "clustering.device")
    mean, std = fit_normaliser(states)
    batches = batches_to(make_batches((states - mean) / std, offsets, cfg.batch_size), device)
    gen = torch.Generator().manual_seed(seed)
    ae = SequenceAutoencoder(states.shape[1], cfg.hidden_size, cfg.latent_size, cfg.pooling)
    ae.reset_parameters(gen)  # drawn on the CPU from the local generator, then moved
    ae.to(device)
    _pretrain(ae, batches, cfg, gen, metrics)
    ae.eval()
    z = encode_all(ae, batches, n)
    centroids = kmeans_centroids(z.cpu().numpy(), cfg.k, seed, cfg.kmeans_n_init)
    if cfg.method != "lstm_dec" or cfg.dec_epochs == 0:
        return ae.cpu(), mean, std, centroids
    centroids = _dec_train(ae, batches, n, centroids, cfg, gen, device, metrics)
    return ae.cpu(), mean, std, centroids


def fit_lstm(
    dataset, states: np.ndarray, offsets: np.ndarray, cfg: ClusterConfig, seed: int, metrics: dict
) -> Fitted:
    """lstm_dec / lstm_kmeans: the trained autoencoder's latents, nearest centroid each."""
    # Torch's global RNG is untouched (local generator); fork it anyway so nothing inside
    # torch that might draw from it (e.g. a future dropout) leaks state to the caller.
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        ae, mean, std, centroids = _train_lstm(states, offsets, cfg, seed, metrics)
    model = ClusterModel(
        cfg.method,
        cfg.model_dump(),
        states.shape[1],
        mean,
        std,
        centroids,
        ae,
        tuple(dataset.feature_names),
    )
    return Fitted(None, model.features(dataset), model)
