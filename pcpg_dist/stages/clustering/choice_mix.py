"""A mixture of choice models over what each legal move does (a latent-class conditional logit).

Where a move id does not say what the styles weigh (chess: an id is a from-square and a
direction; the styles prefer captures, checks, pawn pushes or development) a policy over ids sees
most ids a handful of times, and a mixture of such policies lands at chance. Given ``F`` numbers
per legal move that describe what it does (a game's own move features), each style is a linear
preference over them: move ``a`` in state ``s`` is chosen with probability
``exp(w_c . phi(s, a)) / sum_b exp(w_c . phi(s, b))`` over the legal ``b``, and a trajectory's
likelihood under style ``c`` is the product over its moves. EM fits the ``k`` preference vectors
and the style shares; each M-step is one convex problem (L-BFGS, a small ridge) for all ``k``.

The moves are given as *pairs*: one row of ``phi`` per (step, legal move), grouped by step in
order, with ``starts`` (where each step's pairs begin) and ``chosen`` (each step's chosen pair).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
from scipy.optimize import minimize
from scipy.special import logsumexp, softmax

from pcpg_dist.common.errors import DataError


@dataclass(frozen=True)
class ChoicePairs:
    """The legal moves of every decision step: ``phi`` (pairs, F) their features, ``starts``
    (steps + 1,) where each step's pairs begin, ``chosen`` (steps,) the index of the taken pair,
    ``steps_of`` (n + 1,) where each trajectory's steps begin."""

    phi: np.ndarray
    starts: np.ndarray
    chosen: np.ndarray
    steps_of: np.ndarray

    def __post_init__(self) -> None:
        steps = len(self.starts) - 1
        if self.phi.ndim != 2 or len(self.phi) != self.starts[-1] or self.starts[0] != 0:
            raise DataError(
                f"move features: need one row per legal move ({self.starts[-1]}), "
                f"got shape {self.phi.shape}"
            )
        if not np.isfinite(self.phi).all():
            raise DataError("move features: a move's features hold NaN or infinite values")
        if (np.diff(self.starts) < 1).any():
            raise DataError("move features: every decision step needs at least one legal move")
        if len(self.chosen) != steps or self.steps_of[-1] != steps:
            raise DataError(f"move features: {len(self.chosen)} chosen moves for {steps} steps")
        inside = (self.chosen >= self.starts[:-1]) & (self.chosen < self.starts[1:])
        if not inside.all():
            raise DataError(
                f"move features: step {int(np.argmin(inside))} chose a move it lists as illegal"
            )

    @cached_property
    def phi_t(self) -> np.ndarray:
        """(F, pairs) float32: the features as the fit's products read them (4-7x faster)."""
        return np.ascontiguousarray(self.phi.T, dtype=np.float32)

    @cached_property
    def counts(self) -> np.ndarray:
        """(steps,) how many legal moves each step has."""
        return np.diff(self.starts)


def _standardisation(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mean, std) of each feature over the legal moves; a feature that never varies keeps std 1."""
    sd = phi.std(axis=0)
    return phi.mean(axis=0), np.where(sd > 0, sd, 1.0)


def _step_loglik(pairs: ChoicePairs, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Under each style's utilities ``u`` (k, pairs), float32: (k, steps) the chosen moves'
    log-probabilities (float64), (k, pairs) each legal move's exp(utility - its step's top) and
    (k, steps) their sums (a move's probability is its exp over its step's sum)."""
    top = np.maximum.reduceat(u, pairs.starts[:-1], axis=1)
    e = np.exp(u - np.repeat(top, pairs.counts, axis=1))
    z = np.add.reduceat(e, pairs.starts[:-1], axis=1)
    ll = (u[:, pairs.chosen] - top).astype(np.float64) - np.log(z.astype(np.float64))
    return ll, e, z


def _utilities(pairs: ChoicePairs, w: np.ndarray) -> np.ndarray:
    """(k, pairs) each legal move's utility under each of the ``k`` preference vectors ``w``."""
    return w.astype(np.float32) @ pairs.phi_t


def trajectory_loglik(pairs: ChoicePairs, w: np.ndarray) -> np.ndarray:
    """(n, k) each trajectory's log-likelihood under each of the ``k`` preference vectors ``w``
    (k, F)."""
    ll, _, _ = _step_loglik(pairs, _utilities(pairs, w))
    return np.add.reduceat(ll, pairs.steps_of[:-1], axis=1).T


def _m_step(
    pairs: ChoicePairs, resp_steps: np.ndarray, w0: np.ndarray, ridge: float, maxiter: int
) -> np.ndarray:
    """The preference vectors (k, F) maximising the log-likelihood weighted by ``resp_steps``
    (k, steps), by L-BFGS from ``w0``."""
    k, f = w0.shape
    total = resp_steps.sum(axis=1)  # (k,)
    taken = pairs.phi_t[:, pairs.chosen].astype(np.float64) @ resp_steps.T  # (F, k)

    def objective(flat: np.ndarray) -> tuple[float, np.ndarray]:
        w = flat.reshape(k, f)
        ll, e, z = _step_loglik(pairs, _utilities(pairs, w))
        value = -(resp_steps * ll).sum() + ridge * total @ (w * w).sum(axis=1)
        # d ll / d w_c = phi_chosen - sum_a p_a phi_a, weighted by the step's responsibility
        weight = e * np.repeat((resp_steps / z).astype(np.float32), pairs.counts, axis=1)
        offered = pairs.phi_t @ weight.T
        grad = (taken - offered).T
        return float(value), (-grad + 2 * ridge * total[:, None] * w).ravel()

    got = minimize(objective, w0.ravel(), jac=True, method="L-BFGS-B", options={"maxiter": maxiter})
    return got.x.reshape(k, f)


def _em(
    pairs: ChoicePairs, resp: np.ndarray, w: np.ndarray, rounds: int, maxiter: int, ridge: float
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """``rounds`` of EM from responsibilities ``resp`` (n, k) and weights ``w``: (the total
    log-likelihood, the weights, the log shares, the (n, k) log joint scores)."""
    steps_per_traj = np.diff(pairs.steps_of)
    for _ in range(rounds):
        w = _m_step(pairs, np.repeat(resp, steps_per_traj, axis=0).T, w, ridge, maxiter)
        log_share = np.log(np.clip(resp.mean(axis=0), 1e-6, None))
        scores = trajectory_loglik(pairs, w) + log_share
        new = np.exp(scores - logsumexp(scores, axis=1, keepdims=True))
        done = np.abs(new - resp).max() < 1e-4
        resp = new
        if done:
            break
    return float(logsumexp(scores, axis=1).sum()), w, log_share, scores


@dataclass(frozen=True)
class ChoiceFit:
    """A fitted mixture: ``w`` (k, F) the styles' preferences over the standardised features
    (``mean``, ``std``: the fit's standardisation), ``log_share`` (k,), and on the fitted log the
    ``labels`` (n,), ``margins`` (n,, nats between the best and the next style) and the
    log-likelihood per move."""

    w: np.ndarray
    log_share: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    labels: np.ndarray
    margins: np.ndarray
    loglik: float

    def scores(self, pairs: ChoicePairs) -> np.ndarray:
        """(n, k) each trajectory of ``pairs`` (raw features): log share + log-likelihood."""
        return choice_scores(pairs, self.w, self.log_share, self.mean, self.std)


def choice_scores(
    pairs: ChoicePairs, w: np.ndarray, log_share: np.ndarray, mean: np.ndarray, std: np.ndarray
) -> np.ndarray:
    """(n, k) each trajectory of ``pairs`` (raw features, standardised by ``mean`` and ``std``):
    log share + log-likelihood of its moves under each preference of ``w``."""
    moved = replace(pairs, phi=(pairs.phi - mean) / std)
    return trajectory_loglik(moved, w) + log_share


def posteriors(scores: np.ndarray) -> np.ndarray:
    """(n, k) float32: each trajectory's posterior over the styles from its (n, k) scores."""
    return softmax(scores, axis=1).astype(np.float32)


def fit_choice_mix(
    pairs: ChoicePairs,
    k: int,
    seed: int,
    starts: int = 8,
    rounds: int = 40,
    ridge: float = 1e-3,
    threads: int = 1,
) -> ChoiceFit:
    """EM from ``starts`` starting partitions (k-means on the revealed preferences, then random
    soft ones), each run 8 short rounds (``threads`` of them at a time); the start of the highest
    log-likelihood is run on to ``rounds``. The features are standardised first (the ridge is on
    their weights). The result does not depend on ``threads``."""
    from sklearn.cluster import KMeans
    from threadpoolctl import threadpool_limits

    n = len(pairs.steps_of) - 1
    if n < k:
        raise DataError(f"choice_mix: {n} trajectories, fewer than k={k}")
    mean, std = _standardisation(pairs.phi)
    pairs = replace(pairs, phi=(pairs.phi - mean) / std)
    rng = np.random.default_rng(seed)
    prefs = revealed_preferences(pairs)
    prefs = (prefs - prefs.mean(axis=0)) / (prefs.std(axis=0) + 1e-9)
    first = KMeans(k, n_init=4, random_state=seed).fit_predict(prefs)
    draws = []
    for i in range(starts):
        resp = np.eye(k)[first] * 0.9 + 0.1 / k if i == 0 else rng.dirichlet(np.ones(k), size=n)
        draws.append((resp, rng.normal(0.0, 0.1, (k, pairs.phi_t.shape[0]))))
    pairs.counts  # noqa: B018 - computed once, before the threads share it
    # the starts are independent: numpy releases the GIL in their array work, so ``threads``
    # of them run side by side, each with one BLAS thread (the same numbers as one after another)
    with threadpool_limits(1), ThreadPoolExecutor(max(1, min(threads, starts))) as pool:
        tried = list(pool.map(lambda d: _em(pairs, *d, 8, 5, ridge), draws))
    _, w, _, scores = max(tried, key=lambda t: t[0])
    resp = np.exp(scores - logsumexp(scores, axis=1, keepdims=True))
    total, w, log_share, scores = _em(pairs, resp, w, rounds, 20, ridge)
    ordered = np.sort(scores, axis=1)
    return ChoiceFit(
        w,
        log_share,
        mean,
        std,
        scores.argmax(axis=1),
        ordered[:, -1] - ordered[:, -2],
        total / len(pairs.chosen),
    )


def revealed_preferences(pairs: ChoicePairs) -> np.ndarray:
    """(n, F) per trajectory: the mean over its moves of the chosen move's features less the mean
    of the legal moves' (what it picked beyond what was on offer)."""
    mean_legal = np.add.reduceat(pairs.phi, pairs.starts[:-1], axis=0) / pairs.counts[:, None]
    beyond = pairs.phi[pairs.chosen] - mean_legal
    return np.add.reduceat(beyond, pairs.steps_of[:-1], axis=0) / np.diff(pairs.steps_of)[:, None]


def supervised_accuracy(pairs: ChoicePairs, styles: np.ndarray, cv, ridge: float = 1e-3) -> float:
    """The supervised form of :func:`fit_choice_mix` (a member of the ceiling's panel): per fold,
    one choice model per style fitted to the training trajectories' moves, and each test
    trajectory given to the style under which its moves are most likely (log share included).
    Mean accuracy over the folds of ``cv``."""
    k = int(styles.max()) + 1
    mean, std = _standardisation(pairs.phi)
    pairs = replace(pairs, phi=(pairs.phi - mean) / std)
    steps = np.diff(pairs.steps_of)
    scores = []
    for train, test in cv.split(np.zeros(len(styles)), styles):
        resp = np.zeros((len(styles), k))
        resp[train, styles[train]] = 1.0
        w0 = np.zeros((k, pairs.phi_t.shape[0]))
        w = _m_step(pairs, np.repeat(resp, steps, axis=0).T, w0, ridge, 100)
        share = np.log(np.clip(resp[train].mean(axis=0), 1e-6, None))
        guess = (trajectory_loglik(pairs, w)[test] + share).argmax(axis=1)
        scores.append(float((guess == styles[test]).mean()))
    return float(np.mean(scores))
