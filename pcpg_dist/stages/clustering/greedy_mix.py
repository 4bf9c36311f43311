"""``greedy_mix``: a mixture of k greedy policies with uniform noise (Step A, discrete states).

The generative story of a play-style dataset, in its simplest form: style c is a policy that
picks one action ``g_c(s)`` in every state; a trajectory follows its style's policy except that,
at a step, with probability ``eps`` it takes a uniformly random valid action. Style is *which*
action a player prefers; skill is how often they stray. A free mixture of policies lacks that
split: there a cluster can also explain "noisy players", so it clusters by skill as readily as by
style (``bag_mop``, docs/clustering.md). Here every cluster is a deterministic policy and the
noise is the same uniform stray for all of them.

For one step, ``P(a | s, c) = (1 - eps) [a = g_c(s)] + eps / n(s)`` with ``n(s)`` the valid
actions in s, so ``log P = log(eps / n) + [a = g_c(s)] * lam`` with
``lam = log(1 + (1 - eps) n / eps)``: every step votes ``lam`` for its action. The greedy action
of each (cluster, state) is never fixed: it is marginalised under a uniform prior over the valid
actions, so a state that a cluster's trajectories rarely visit says little about it:

    F_c(s) = log sum_a exp(V_c[s, a]) - log n(s),   V_c[s, a] = sum of lam over c's steps (s, a).

The collapsed log-likelihood of a labelling is ``sum_steps log(eps / n) + sum_c sum_s F_c(s)``
plus the multinomial prior of the cluster sizes.

**Fit.** Coordinate ascent on it (a numba kernel): trajectory after trajectory moves to the
cluster that raises it most (its own votes taken out first, so a trajectory never votes for
itself), sweep after sweep until none moves. Every move raises the likelihood, so it cannot
cycle. Trajectories with the same multiset of (state, action) steps are the same to this model,
so they are collapsed once and carry their count.

**Starts.** Ascent refines a partition; it does not find one, and it cannot move a *group*: a
group of one style's trajectories that the start put with another style can hold together there
(each is best where the rest of its group is). Starts with more clusters than k give such a group
a cluster of its own; merging clusters down to k by likelihood then joins it to the style it
belongs to. So the caller (``pcpg_dist.stages.clustering.bags``) passes k-means starts with k, k + 1 and
k + 2 clusters, each from three k-means seeds (on E1-E5 at three data seeds and four clustering
seeds, one k-means seed per size left 4 of 60 fits more than a point below the supervised
ceiling, three seeds 1; docs/clustering.md).

**Split and merge.** Starts with more clusters free a group only when k-means happened to give it
a cluster of its own. After the best start, :func:`split_merge` tries the moves of SMEM (Ueda et
al. 2000): merge two clusters, split another in two, refine, keep what raises the likelihood.
On E1-E5 over three data seeds and four clustering seeds this took the fits within a point of the
supervised ceiling from 59 of 60 to 60 of 60 (docs/clustering.md).

**Noise level.** One ``eps`` shared by all trajectories. Which one matters where a group sits in
another style's cluster (a near-tie that a small eps breaks and a large one keeps), so the ascent
runs once per level of :data:`NOISE_LEVELS`, and of all starts and levels the labelling with the
highest *profile* likelihood (maximised over eps on
:data:`.greedy_likelihood.NOISE_GRID`) is kept. No labels are read anywhere.

The likelihood and the ascent live in :mod:`.greedy_likelihood`; this module searches with them.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.optimize import linear_sum_assignment

from pcpg_dist.stages.clustering.features import dedup_rows
from pcpg_dist.stages.clustering.greedy_likelihood import (
    Steps,
    ascend,
    cluster_counts,
    cluster_terms,
    marginal,
    per_state_votes,
    profile_log_likelihood,
    size_term,
    vote_weights,
    votes,
)

#: the shared noise levels the ascent is run at (the best by profile likelihood is kept)
NOISE_LEVELS = (0.05, 0.1, 0.15, 0.2, 0.3)


@dataclass(frozen=True)
class GreedyMixFit:
    labels: np.ndarray  # (n,) per trajectory
    votes: np.ndarray  # (k, S, A) of the final labels at ``noise``
    log_share: np.ndarray  # (k,) log cluster sizes / n
    noise: float  # the profile-likelihood noise level of the final labels
    noise_start: float  # the level whose ascent was kept
    start_clusters: int  # the size of the start whose result was kept
    sweeps: int
    moved: float  # fraction of trajectories whose label differs from the first start
    log_likelihood: float  # the profile log-likelihood of the final labels
    split_merges: int = 0  # split-and-merge moves accepted after the best start


def _merge_gain(
    steps: Steps,
    counts: np.ndarray,
    terms: np.ndarray,
    sizes: np.ndarray,
    a: int,
    b: int,
    eps: float,
) -> tuple[float, float]:
    """``(change in log-likelihood, merged cluster's F term)`` of merging clusters a and b: only the
    pair's F terms and size terms change."""
    merged = float(cluster_terms(steps, (counts[a] + counts[b])[None], eps)[0])
    total = sizes.sum()
    delta = (
        merged
        - terms[a]
        - terms[b]
        + size_term(sizes[a] + sizes[b], total)
        - size_term(sizes[a], total)
        - size_term(sizes[b], total)
    )
    return delta, merged


def merge_down(
    steps: Steps, mult: np.ndarray, labels: np.ndarray, k: int, eps: float
) -> np.ndarray:
    """Merge clusters pairwise, each time the pair whose merge keeps the likelihood highest, until k.

    Only the merged pair's terms change, so each candidate costs one cluster's F over the states.
    """
    labels = np.array(labels, np.int64)
    n_clusters = int(labels.max(initial=0)) + 1
    counts = cluster_counts(steps, labels, mult, n_clusters)
    terms = cluster_terms(steps, counts, eps)
    sizes = np.bincount(labels, mult, minlength=n_clusters).astype(np.float64)
    while n_clusters > k:
        best = None
        for a in range(n_clusters):
            for b in range(a + 1, n_clusters):
                delta, merged_term = _merge_gain(steps, counts, terms, sizes, a, b, eps)
                if best is None or delta > best[0]:
                    best = (delta, a, b, merged_term)
        _, a, b, merged_term = best
        counts[a] += counts[b]
        terms[a], sizes[a] = merged_term, sizes[a] + sizes[b]
        keep = np.arange(n_clusters) != b
        counts, terms, sizes = counts[keep], terms[keep], sizes[keep]
        labels = np.where(labels == b, a, labels)
        labels[labels > b] -= 1
        n_clusters -= 1
    return labels


def split_merge(
    steps: Steps,
    mult: np.ndarray,
    labels: np.ndarray,
    k: int,
    eps: float,
    max_sweeps: int = 100,
    seed: int = 0,
    max_rounds: int = 10,
    max_pairs: int = 6,
) -> tuple[np.ndarray, tuple[float, float], int]:
    """Split-and-merge moves from a converged labelling (SMEM, Ueda et al. 2000), for the group
    that no single move shifts and that no start happened to free.

    A candidate merges two clusters (the ``max_pairs`` pairs whose merge costs the least
    likelihood) and splits another in two (2-means on the members' normalised (state, action)
    counts, seeded); the ascent at ``eps`` then refines it. The candidate with the highest profile
    likelihood replaces the labelling if it beats it, and the moves repeat until none does (at most
    ``max_rounds`` rounds). Returns ``(labels, (profile log-likelihood, its eps), moves accepted)``.
    """
    from sklearn.cluster import KMeans
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.preprocessing import normalize

    labels = np.array(labels, np.int64)
    best = profile_log_likelihood(steps, mult, labels, k)
    scored = {labels.tobytes(): best}  # candidates often refine back to a labelling already scored
    rows = normalize(steps.counts)
    accepted = 0
    for _ in range(max_rounds):
        counts = cluster_counts(steps, labels, mult, k)
        terms = cluster_terms(steps, counts, eps)
        sizes = np.bincount(labels, mult, minlength=k).astype(np.float64)
        gains = [
            (_merge_gain(steps, counts, terms, sizes, a, b, eps)[0], a, b)
            for a in range(k)
            for b in range(a + 1, k)
        ]
        top, halves = None, {}  # a cluster outside the merged pair splits the same way every time
        for _, a, b in sorted(gains, key=lambda t: -t[0])[:max_pairs]:
            merged = np.where(labels == b, a, labels)  # label b is free now
            for c in range(k):
                members = np.flatnonzero(merged == c)
                if c == b or len(members) < 2:
                    continue
                group = members.tobytes()
                if group not in halves:
                    with warnings.catch_warnings():  # members whose rows are all proportional
                        warnings.simplefilter("ignore", ConvergenceWarning)
                        halves[group] = (
                            KMeans(n_clusters=2, n_init=3, random_state=seed)
                            .fit(rows[members], sample_weight=mult[members])
                            .labels_
                        )
                half = halves[group]
                if half.min() == half.max():
                    continue
                start = merged.copy()
                start[members[half == 1]] = b
                moved, _ = ascend(steps, mult, start, k, eps, max_sweeps)
                key = moved.tobytes()
                if key not in scored:
                    scored[key] = profile_log_likelihood(steps, mult, moved, k)
                if scored[key][0] > best[0] + 1e-6 and (top is None or scored[key][0] > top[0][0]):
                    top = (scored[key], moved)
        if top is None:
            break
        best, labels = top
        accepted += 1
    return labels, best, accepted


def fit(
    steps: Steps,
    starts: list[np.ndarray],
    k: int,
    max_sweeps: int = 100,
    noise_levels: tuple[float, ...] = NOISE_LEVELS,
    seed: int = 0,
    split_merge_rounds: int = 10,
) -> GreedyMixFit:
    """Refine the start labellings (each (n,), with k or more clusters) as the module doc says;
    a start with more than k clusters is refined at its own size, merged down to k
    (:func:`merge_down`) and refined again. The result with the highest profile likelihood over
    all starts and noise levels is kept (the first on a tie), then improved by
    :func:`split_merge` at the noise level it was found at (at most ``split_merge_rounds``
    moves; 0 turns it off). Deterministic for one ``seed`` (the split's 2-means).

    Rows with identical (state, action) counts are the same to the model and are collapsed first.
    """
    first, mult, inv = dedup_rows(steps.counts)
    uniq = Steps(steps.counts[first], steps.valid, steps.n_actions)
    best, scored = None, {}
    for init in starts:
        init = np.asarray(init, np.int64)
        size = int(init.max(initial=0)) + 1
        start = np.zeros((len(first), max(size, k)))  # copies of one row take their majority label
        np.add.at(start, (inv, init), 1.0)
        start = start.argmax(1)
        for eps in noise_levels:
            labels, sweeps = ascend(uniq, mult, start, max(size, k), eps, max_sweeps)
            if size > k:
                labels, more = ascend(
                    uniq, mult, merge_down(uniq, mult, labels, k, eps), k, eps, max_sweeps
                )
                sweeps += more
            key = labels.tobytes()
            if key not in scored:  # several starts and levels often end in the same labelling
                scored[key] = profile_log_likelihood(uniq, mult, labels, k)
            ll, eps_hat = scored[key]
            if best is None or ll > best[0] + 1e-9:
                best = (ll, eps_hat, eps, size, labels, sweeps)
    ll, eps_hat, eps0, size, labels, sweeps = best
    split_merges = 0
    if split_merge_rounds > 0 and k > 1 and len(first) > k:
        labels, (ll, eps_hat), split_merges = split_merge(
            uniq, mult, labels, k, eps0, max_sweeps, seed, split_merge_rounds
        )
    # number the clusters as the first start does (most shared trajectories), so the labels of
    # a refined start stay comparable with it
    first_start = np.asarray(starts[0], np.int64)
    overlap = np.zeros((k, max(k, int(first_start.max(initial=0)) + 1)))
    np.add.at(overlap, (labels[inv], first_start), 1.0)
    rows, cols = linear_sum_assignment(-overlap)
    rename = np.arange(k)
    rename[rows] = cols
    labels = rename[labels]
    v = votes(uniq, labels, mult, k, eps_hat)
    sizes = np.bincount(labels, mult, minlength=k)
    out = labels[inv]
    return GreedyMixFit(
        out,
        v,
        np.log(np.maximum(sizes, 1e-3) / mult.sum()),
        eps_hat,
        eps0,
        size,
        sweeps,
        float((out != first_start).mean()),
        ll,
        split_merges,
    )


def scores(
    steps: Steps,
    weights: sparse.csr_matrix,
    v: np.ndarray,
    log_share: np.ndarray,
    own: np.ndarray | None = None,
) -> np.ndarray:
    """(n, k) gain in collapsed log-likelihood from adding each trajectory to each cluster's votes.

    ``own``: each trajectory's cluster in the fit that made ``v``; its own cluster is then scored
    without its votes, as the ascent scores a move (so it never votes for itself).
    """
    indptr, state, d = per_state_votes(weights, steps.n_actions)
    traj = np.repeat(np.arange(weights.shape[0]), np.diff(indptr))
    valid = steps.valid[state]
    out = np.zeros((weights.shape[0], v.shape[0]))
    for c in range(v.shape[0]):
        base = v[c][state]
        if own is not None:
            base = base - np.where((own[traj] == c)[:, None], d, 0.0)
        out[:, c] = np.bincount(
            traj, marginal(base + d, valid) - marginal(base, valid), minlength=weights.shape[0]
        )
    return out + log_share[None, :]


def fit_scores(steps: Steps, fit: GreedyMixFit) -> np.ndarray:
    """(n, k) each trajectory's :func:`scores` under the fitted clusters, its own cluster's votes
    without it. The fit's label is the row maximum for nearly every trajectory (the ascent stopped
    where none moves, at the noise level it ran at; these scores are at the fitted level)."""
    return scores(steps, vote_weights(steps, fit.noise), fit.votes, fit.log_share, fit.labels)


def predict(steps: Steps, v: np.ndarray, log_share: np.ndarray, eps: float) -> np.ndarray:
    """Labels of (new) trajectories under fitted votes: the cluster their steps raise most."""
    return scores(steps, vote_weights(steps, eps), v, log_share).argmax(1)
