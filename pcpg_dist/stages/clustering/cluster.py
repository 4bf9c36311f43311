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
- ``visits_kmeans`` — k-means (cosine) on which distinct states a trajectory visits.
- ``bag_kmeans`` — weighted k-means (cosine) on distinct visitation rows: visited states,
  state-actions and the final state (pcpg_dist/stages/clustering/features.py), duplicates as weights.
- ``bag_mop`` — a mixture of k policies pi_c(a | s) fitted by EM from bag_kmeans' labels.
- ``greedy_mix`` — a mixture of k greedy policies with one uniform noise level, fitted by
  coordinate ascent from bag_kmeans' labels (pcpg_dist/stages/clustering/greedy_mix.py): style = which action.
- ``bag_auto`` (the default) — greedy_mix on discrete states, the paper's lstm_dec on continuous
  ones (where a state is almost never seen twice, a per-state policy says nothing).
- ``policy_mix`` — a mixture of k neural policies pi_c(a | s) (shared trunk, k heads) fitted by
  hard EM over whole trajectories, started from k-means on the gain and mean of the features that
  never decrease within a trajectory (counters); for continuous states (MiniDungeons).

Determinism: all randomness comes from ``seed`` (a local ``torch.Generator`` and k-means'
``random_state``); with the same data, seed and torch thread count the labels are identical.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch
from scipy import sparse
from scipy.optimize import linear_sum_assignment
from scipy.special import logsumexp
from sklearn.cluster import KMeans
from sklearn.metrics import adjusted_rand_score, normalized_mutual_info_score, silhouette_score

from pcpg_dist.common.devices import resolve_device
from pcpg_dist.common.errors import DataError
from pcpg_dist.config.stages import ClusterConfig
from pcpg_dist.stages.clustering.models import (
    BAG_METHODS,
    ClusterModel,
    PolicyMixture,
    SequenceAutoencoder,
    batches_to,
    checked_sequences,
    encode_all,
    fit_normaliser,
    load_model,
    make_batches,
    policy_inputs,
    state_vocabulary,
    summary_features,
    trajectory_scores,
    visit_features,
)

__all__ = [
    "ClusterConfig",
    "Clustering",
    "ClusterModel",
    "cluster",
    "clustering_metrics",
    "cluster_sizes",
    "counter_summary",
    "hungarian_mapping",
    "load_model",
    "monotone_features",
]


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
    device = resolve_device(cfg.device, "clustering.device")
    mean, std = fit_normaliser(states)
    batches = batches_to(make_batches((states - mean) / std, offsets, cfg.batch_size), device)
    gen = torch.Generator().manual_seed(seed)
    ae = SequenceAutoencoder(states.shape[1], cfg.hidden_size, cfg.latent_size, cfg.pooling)
    ae.reset_parameters(gen)  # drawn on the CPU from the local generator, then moved
    ae.to(device)
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

    ae.eval()
    z = encode_all(ae, batches, n)
    centroids = _kmeans(z.cpu().numpy(), cfg.k, seed, cfg.kmeans_n_init)
    if cfg.method != "lstm_dec" or cfg.dec_epochs == 0:
        return ae.cpu(), mean, std, centroids

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
    return ae.cpu(), mean, std, mu.detach().cpu().numpy().copy()


# --------------------------------------------------------------------- bag clusterers
def falls_back_to_lstm(dataset) -> bool:
    """Whether ``bag_auto`` clusters ``dataset`` with lstm_dec (continuous states) rather than
    greedy_mix."""
    return _mostly_distinct_states(checked_sequences(dataset)[0])


def _mostly_distinct_states(states: np.ndarray) -> bool:
    """Whether more than half the state rows are distinct (continuous states: bags are useless)."""
    from pcpg_dist.stages.clustering.models import row_ids

    _, first = row_ids(states)
    return len(first) > 0.5 * len(states)


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


def _sample_distances(
    x: sparse.csr_matrix, sample: int, seed: int, row_of: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(indices, euclidean distances) of the rows sklearn's ``silhouette_score(sample_size=sample,
    random_state=seed)`` would draw: the same silhouette, from one Gram product over the sample's
    *distinct* rows (``row_of[i]`` = a representative row of row i, from :func:`dedup_rows`)
    instead of a sparse-to-dense product per call (86 % of bag_auto's time before)."""
    n = x.shape[0]
    idx = np.random.RandomState(seed).permutation(n)[: min(sample, n)]
    reps = idx if row_of is None else row_of[idx]
    uniq, back = np.unique(reps, return_inverse=True)
    xs = x[uniq]
    gram = np.asarray((xs @ xs.T).todense(), np.float64)
    sq = np.diag(gram).copy()
    du = np.sqrt(np.maximum(sq[:, None] + sq[None, :] - 2.0 * gram, 0.0))
    np.fill_diagonal(du, 0.0)
    return idx, du[np.ix_(back, back)]


def _silhouette_precomputed(dist: np.ndarray, labels: np.ndarray) -> float | None:
    """Silhouette from a distance matrix; None when the sample holds fewer than 2 clusters."""
    used = len(np.unique(labels))
    if not 2 <= used < len(labels):
        return None
    return float(silhouette_score(dist, labels, metric="precomputed"))


def _fit_bag(
    dataset,
    states: np.ndarray,
    offsets: np.ndarray,
    cfg: ClusterConfig,
    seed: int,
    metrics: dict[str, float],
):
    """bag_kmeans / bag_mop / greedy_mix / bag_auto on visitation rows; returns (labels, x, model).

    Every one starts from weighted k-means on the distinct bag rows; bag_mop refines that by a
    free mixture of policies, greedy_mix and bag_auto by a mixture of greedy policies with
    uniform noise (pcpg_dist/stages/clustering/greedy_mix.py).
    """
    from sklearn.preprocessing import normalize

    from pcpg_dist.stages.clustering import greedy_mix
    from pcpg_dist.stages.clustering.features import bag_matrix, dedup_rows, fit_vocabulary

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
    elif cfg.method in ("greedy_mix", "bag_auto"):
        steps = greedy_mix.Steps.of_dataset(dataset, states, vocab.states)
        # starts: k-means with k, k + 1 and k + 2 clusters, from three seeds (greedy_mix.py says why)
        starts = [km.labels_[inv]] + [
            KMeans(n_clusters=kk, n_init=cfg.kmeans_n_init, random_state=seed + r)
            .fit(xu, sample_weight=w)
            .labels_[inv]
            for r in range(3)
            for kk in (k, k + 1, k + 2)
            if kk <= len(first) and (r, kk) != (0, k)
        ]
        fit = greedy_mix.fit(steps, starts, cfg.k, seed=seed)
        labels, greedy = fit.labels, (fit.votes, fit.log_share, fit.noise)
        margins = _margins(greedy_mix.fit_scores(steps, fit), labels)
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
    else:
        labels = km.labels_[inv]
    idx, dist = _sample_distances(x, cfg.silhouette_sample, seed, first[inv])
    s = _silhouette_precomputed(dist, labels[idx])
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
    return labels.astype(np.int64), x, model, margins


def _margins(scores: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(n,) each row's score at its label minus its best score elsewhere (n, k scores); a lone
    cluster has no other: the largest float (finite, so the margins survive JSON)."""
    n = len(labels)
    if scores.shape[1] < 2:
        return np.full(n, np.finfo(np.float64).max)
    own = scores[np.arange(n), labels]
    other = scores.copy()
    other[np.arange(n), labels] = -np.inf
    return own - other.max(axis=1)


def monotone_features(states: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Indices of the state features that never decrease within any trajectory and do change
    somewhere: counters (steps, kills, treasure, ...), found without labels."""
    step = np.diff(states.astype(np.float64), axis=0)
    within = np.ones(len(step), bool)
    within[offsets[1:-1] - 1] = False  # the step from one trajectory's last row to the next's first
    step = step[within]
    if not len(step):
        return np.zeros(0, np.int64)
    return np.flatnonzero((step >= -1e-9).all(axis=0) & (step > 1e-9).any(axis=0))


def counter_summary(states: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Per trajectory: each counter's gain (last - first) and mean, standardised; without counters,
    the standardised [length, final state, mean state] of ``summary_kmeans``."""
    cols = monotone_features(states, offsets)
    if cols.size:
        x = states[:, cols].astype(np.float64)
        gain = x[offsets[1:] - 1] - x[offsets[:-1]]
        feats = np.column_stack(
            [gain, np.add.reduceat(x, offsets[:-1], axis=0) / np.diff(offsets)[:, None]]
        )
    else:
        feats = summary_features(states, offsets)
    mean, std = fit_normaliser(feats)
    return (feats - mean) / std


def _fit_policy_mix(
    dataset,
    states: np.ndarray,
    offsets: np.ndarray,
    cfg: ClusterConfig,
    seed: int,
    metrics: dict[str, float],
) -> tuple[np.ndarray, PolicyMixture, np.ndarray, np.ndarray]:
    """Hard EM for a mixture of k policies over whole trajectories (call inside a forked torch RNG).

    Start: k-means on :func:`counter_summary`. Each round refits the k policy heads (and the shared
    trunk) to the current labels by ``policy_steps`` full-batch Adam steps on the steps' log
    likelihood, then moves every trajectory to the policy under which its actions are most likely
    (+ log cluster share). Stops when fewer than ``em_tol`` of the labels moved.
    """
    n = len(offsets) - 1
    mean, std = fit_normaliser(states)
    inputs = policy_inputs(dataset, states, mean, std)
    s, a, valid, traj = inputs
    if not len(a):
        raise DataError(
            f"policy_mix: {dataset.domain}-{dataset.env} has no step with an action "
            "(it clusters by the actions taken)"
        )
    labels = (
        KMeans(n_clusters=cfg.k, n_init=cfg.kmeans_n_init, random_state=seed)
        .fit_predict(counter_summary(states, offsets))
        .astype(np.int64)
    )
    device = resolve_device(cfg.device, "clustering.device")
    gen = torch.Generator().manual_seed(seed)
    policy = PolicyMixture(states.shape[1], cfg.hidden_size, cfg.k, dataset.n_actions)
    policy.reset_parameters(gen)  # drawn on the CPU from the local generator, then moved
    policy.to(device)
    inputs = tuple(t.to(device) for t in inputs)
    s, a, valid, traj = inputs
    opt = torch.optim.Adam(policy.parameters(), lr=cfg.policy_lr)
    rounds, moved = 0, 1.0
    while rounds < cfg.em_iterations:
        rounds += 1
        own = torch.from_numpy(labels).to(device)[traj]
        with torch.no_grad():
            share = np.bincount(labels, minlength=cfg.k) / n
            policy.log_prior.copy_(torch.from_numpy(np.log(np.maximum(share, 1e-12))).float())
        for _ in range(cfg.policy_steps):
            lp = policy.step_log_probs(s, a, valid)
            loss = -lp.gather(0, own[None]).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        with torch.no_grad():
            new = trajectory_scores(policy, inputs, n).argmax(0).cpu().numpy().astype(np.int64)
        moved = float((new != labels).mean())
        labels = new
        if moved < cfg.em_tol:
            break
    # the prior stays the one the final labels were drawn with, so predict() gives them back
    metrics.update(
        {"em_rounds": float(rounds), "em_last_moved": moved, "policy_nll": float(loss.detach())}
    )
    return labels, policy.cpu(), mean, std


def cluster(dataset, cfg: ClusterConfig, seed: int) -> Clustering:
    """Cluster ``dataset``'s trajectories into ``cfg.k`` play-styles; never reads ``dataset.styles``.

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
    if cfg.method == "greedy_mix" and _mostly_distinct_states(states):
        raise DataError(
            f"clustering.method greedy_mix: most states of {dataset.domain}-{dataset.env} "
            "occur once (continuous states), so a per-state policy cannot be estimated; "
            "use bag_auto, policy_mix or lstm_dec"
        )
    if cfg.method == "bag_auto" and _mostly_distinct_states(states):
        # Continuous states (Mario): every state is new, a visitation bag says nothing; the
        # sequence model is the one that can still see a style there.
        cfg = cfg.model_copy(update={"method": "lstm_dec"})
        metrics["auto_fell_back_to_lstm"] = 1.0
    config = cfg.model_dump()
    labels = margins = None
    if cfg.method in BAG_METHODS:
        labels, latents, model, margins = _fit_bag(dataset, states, offsets, cfg, seed, metrics)
    elif cfg.method == "visits_kmeans":
        vocab = state_vocabulary(states)
        latents = visit_features(states, offsets, vocab)
        km = KMeans(n_clusters=cfg.k, n_init=cfg.kmeans_n_init, random_state=seed).fit(latents)
        d = states.shape[1]
        model = ClusterModel(
            cfg.method,
            config,
            d,
            np.zeros(d),
            np.ones(d),
            km.cluster_centers_,
            None,
            tuple(dataset.feature_names),
            vocab,
        )
    elif cfg.method == "policy_mix":
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            labels, policy, mean, std = _fit_policy_mix(
                dataset, states, offsets, cfg, seed, metrics
            )
        model = ClusterModel(
            cfg.method,
            config,
            states.shape[1],
            mean,
            std,
            np.eye(cfg.k, dtype=np.float32),
            None,
            tuple(dataset.feature_names),
            policy=policy,
        )
        latents = model.features(dataset)
        with torch.no_grad():
            margins = _margins(
                trajectory_scores(policy, policy_inputs(dataset, states, mean, std), n)
                .T.double()
                .numpy(),
                labels,
            )
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
    if labels is None:
        labels = model.assign(latents)
    if sparse.issparse(latents) and "silhouette" not in metrics:
        idx, dist = _sample_distances(latents, cfg.silhouette_sample, seed)
        s = _silhouette_precomputed(dist, labels[idx])
        if s is not None:
            metrics["silhouette"] = s
    metrics.update(_label_free_metrics(latents, labels, cfg.k, cfg.silhouette_sample, seed))
    return Clustering(
        labels=labels,
        latents=latents,
        metrics=metrics,
        model=model,
        fit_seconds=time.perf_counter() - start,
        margins=margins,
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
    if 2 <= out["n_clusters_used"] < len(labels) and not sparse.issparse(latents):
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
