"""``policy_mix``: a mixture of k neural policies pi_c(a | s) (shared trunk, k heads) fitted by
hard EM over whole trajectories, started from k-means on a per-trajectory style latent
(:mod:`.latent_start`; or, with ``policy_start: counters``, on the gain and mean of the features
that never decrease within a trajectory); for continuous states and discrete ones that rarely
repeat."""

from __future__ import annotations

import warnings

import numpy as np
import torch
from sklearn.cluster import KMeans
from sklearn.exceptions import ConvergenceWarning

from pcpg_dist.common.devices import resolve_device
from pcpg_dist.common.errors import DataError
from pcpg_dist.config.clustering import ClusterConfig
from pcpg_dist.stages.clustering.latent_start import latent_start
from pcpg_dist.stages.clustering.legal_actions import as_legal
from pcpg_dist.stages.clustering.metrics import likelihood_margins
from pcpg_dist.stages.clustering.model import ClusterModel, Fitted
from pcpg_dist.stages.clustering.policy_network import (
    PolicyMixture,
    policy_inputs,
    policy_states,
    posteriors,
    trajectory_scores,
)
from pcpg_dist.stages.clustering.states import fit_normaliser, summary_features


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


def counter_start(seen: np.ndarray, offsets: np.ndarray, cfg: ClusterConfig, seed: int):
    """policy_mix's label-free start: k-means on :func:`counter_summary` of the states the
    policies see (with ``policy_time``, the time step is one more counter)."""
    with warnings.catch_warnings():  # identical summaries (fixed-length logs): fewer centres
        warnings.simplefilter("ignore", ConvergenceWarning)
        kmeans = KMeans(n_clusters=cfg.k, n_init=cfg.kmeans_n_init, random_state=seed)
        return kmeans.fit_predict(counter_summary(seen, offsets))


def reseed_small(
    labels: np.ndarray, scores: np.ndarray, steps: np.ndarray, k: int, min_share: float
) -> int:
    """Re-seed, in place, every cluster left with fewer than ``min_share * n / k`` trajectories:
    it takes the half of the largest cluster that the largest cluster's policy explains worst (mean
    log-likelihood a step). Returns how many clusters were re-seeded.

    Hard EM over whole trajectories collapses: a trajectory's score sums hundreds of steps, so a
    policy fitted to a little more data wins whole styles and the others empty. Measured on the
    design games of the zoo (docs/zoo.md): mujoco_pendulum started from k-means at 238/1/1/0 and
    stayed there (0.254); cartpole lost a style midway (0.744). Re-seeding from the worst-explained
    half gives the emptied policy the trajectories most unlike the big cluster's style (1.000 on
    both). Styles smaller than ``min_share`` of an equal share are merged into others: set 0 there.
    """
    n, done = len(labels), 0
    floor = min_share * n / k
    for c in range(k):
        sizes = np.bincount(labels, minlength=k)
        if sizes[c] >= floor:
            continue
        big = int(sizes.argmax())
        members = np.flatnonzero(labels == big)
        fit = scores[big, members] / np.maximum(steps[members], 1.0)
        labels[members[np.argsort(fit, kind="stable")[: len(members) // 2]]] = c
        done += 1
    return done


#: the first EM round after the latent start trains this many times ``policy_steps``: with 50
#: steps the heads are barely fitted when EM first reassigns, and good starts drift away
#: (docs/zoo.md, "Search or objective?")
LATENT_FIRST_ROUND = 4


def label_free_start(dataset, seen, offsets, inputs, cfg: ClusterConfig, seed: int):
    """(labels, first round's Adam steps or None): policy_mix's start by ``policy_start``."""
    n = len(offsets) - 1
    if cfg.policy_start == "latent":  # a short first round would leave it (docs/zoo.md)
        start = latent_start(inputs, n, cfg, dataset.n_actions, seed)
        return start, LATENT_FIRST_ROUND * cfg.policy_steps
    return counter_start(seen, offsets, cfg, seed), None


ROWS_PER_TRAJECTORY = 64  # the fewest steps a trajectory gives the policies' fit, on average


def fit_sample(steps: int, n_trajectories: int, rows: int, gen: torch.Generator) -> torch.Tensor:
    """The steps policy_mix fits its policies to (sorted indices): every step, or, on a log with
    more than max(``rows``, 64 x ``n_trajectories``) of them, a seeded sample of that many (``rows`` 0:
    every step). Every step is still scored. The policies are small networks: on the zoo's design
    games 32768 steps fit them as well as all 65-206 thousand, 3-10x faster (docs/clustering.md);
    the per-trajectory floor keeps logs of many short trajectories whole (MiniDungeons' 780)."""
    size = max(rows, ROWS_PER_TRAJECTORY * n_trajectories)
    if rows == 0 or size >= steps:
        return torch.arange(steps)
    return torch.randperm(steps, generator=gen)[:size].sort().values


def _policy_view(dataset, states: np.ndarray, cfg: ClusterConfig):
    """(seen, mean, std, inputs): the states the policies see (with ``policy_time``, t is a
    counter too), their normaliser, and :func:`.policy_network.policy_inputs`."""
    seen = policy_states(dataset, states, cfg.policy_time)
    mean, std = fit_normaliser(seen)
    inputs = policy_inputs(dataset, seen, mean, std)
    if not len(inputs[1]):  # the actions
        raise DataError(
            f"policy_mix: {dataset.domain}-{dataset.env} has no step with an action "
            "(it clusters by the actions taken)"
        )
    return seen, mean, std, inputs


def _fit_policy_mix(
    dataset,
    states: np.ndarray,
    offsets: np.ndarray,
    cfg: ClusterConfig,
    seed: int,
    metrics: dict[str, float],
    start: np.ndarray | None = None,
    first_round_steps: int | None = None,
) -> tuple[np.ndarray, PolicyMixture, np.ndarray, np.ndarray]:
    """Hard EM for a mixture of k policies over whole trajectories (call inside a forked torch RNG).

    Start: :func:`label_free_start`, or the labels ``start``; the first round may train
    ``first_round_steps`` (``benchmarks/zoo/search.py``). Each round refits the k heads and the
    trunk to the current labels by ``policy_steps`` full-batch Adam steps on the steps
    :func:`fit_sample` drew, scores every step, moves every trajectory to its most likely policy
    (+ log cluster share), and re-seeds the clusters that
    emptied (:func:`reseed_small`). Stops when fewer than ``em_tol`` of the labels moved.
    """
    n = len(offsets) - 1
    seen, mean, std, inputs = _policy_view(dataset, states, cfg)
    if start is None:
        start, first = label_free_start(dataset, seen, offsets, inputs, cfg, seed)
        first_round_steps = first_round_steps or first
    labels = np.array(start, np.int64)
    device = resolve_device(cfg.device, "clustering.device")
    gen = torch.Generator().manual_seed(seed)
    policy = PolicyMixture(
        states.shape[1], cfg.hidden_size, cfg.k, dataset.n_actions, cfg.policy_time
    )
    policy.reset_parameters(gen)  # drawn on the CPU from the local generator, then moved
    policy.to(device)
    inputs = tuple(t.to(device) for t in inputs)
    s, a, valid, traj = inputs
    opt = torch.optim.Adam(policy.parameters(), lr=cfg.policy_lr)
    rounds, moved, reseeds = 0, 1.0, 0
    fit = fit_sample(len(a), n, cfg.policy_rows, gen).to(device)
    fs, fa, fvalid, ftraj = (t[fit] for t in inputs)
    fvalid = as_legal(fvalid, fa)  # a few legal actions of many: only those are scored
    inputs = (s, a, as_legal(valid, a), traj)  # every round scores every step: found once
    steps = np.bincount(traj.cpu().numpy(), minlength=n).astype(np.float64)
    while rounds < cfg.em_iterations:
        rounds += 1
        own = torch.from_numpy(labels).to(device)[ftraj][None]  # each fitted step's cluster
        with torch.no_grad():
            share = np.bincount(labels, minlength=cfg.k) / n
            policy.log_prior.copy_(torch.from_numpy(np.log(np.maximum(share, 1e-12))).float())
        train_steps = cfg.policy_steps
        if rounds == 1 and first_round_steps is not None:
            train_steps = first_round_steps
        for _ in range(train_steps):
            lp = policy.step_log_probs(fs, fa, fvalid)
            loss = -lp.gather(0, own).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        with torch.no_grad():
            scores = trajectory_scores(policy, inputs, n).double().cpu().numpy()
        new = scores.argmax(0).astype(np.int64)
        last = rounds == cfg.em_iterations  # the last round's labels are its policies' own
        reseeded = 0 if last else reseed_small(new, scores, steps, cfg.k, cfg.policy_min_share)
        reseeds += reseeded
        moved = float((new != labels).mean())
        labels = new
        if moved < cfg.em_tol and not reseeded:  # re-seeded labels are refitted first
            break
    # the prior stays the one the final labels were drawn with, so predict() gives them back
    metrics.update(
        {
            "em_rounds": float(rounds),
            "em_last_moved": moved,
            "em_reseeds": float(reseeds),
            "policy_nll": float(loss.detach()),
            "policy_fit_steps": float(len(fit)),  # of the log's len(a): fit_sample's
        }
    )
    return labels, policy.cpu(), mean, std


def fit_policy_mix(
    dataset, states: np.ndarray, offsets: np.ndarray, cfg: ClusterConfig, seed: int, metrics: dict
) -> Fitted:
    """policy_mix: the EM labels, the posteriors over the k policies as latents, and each
    trajectory's likelihood margin over the next best policy."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        labels, policy, mean, std = _fit_policy_mix(dataset, states, offsets, cfg, seed, metrics)
    model = ClusterModel(
        cfg.method,
        cfg.model_dump(),
        states.shape[1],
        mean,
        std,
        np.eye(cfg.k, dtype=np.float32),
        None,
        tuple(dataset.feature_names),
        policy=policy,
    )
    scores = model.policy_scores(dataset)  # once, for the latents and the margins
    margins = likelihood_margins(scores.T.double().numpy(), labels)
    latents = posteriors(scores)
    return Fitted(labels, latents, model, margins, silhouette=False)
