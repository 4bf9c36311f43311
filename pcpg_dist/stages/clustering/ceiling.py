"""The honest ceiling of Step A: what a classifier *given* the true styles reaches.

Clustering accuracy alone does not say how much is left on the table: some datasets hold
trajectories that no method could tell apart (identical routes of two styles). The ceiling is the
best of a small panel of supervised models, each trained with the true labels on the same
trajectories and 5-fold cross-validated:

- ``linear_bags``: a logistic regression on which distinct states a trajectory visits and which
  (state, action) pairs it takes (binary bag of visits: the discrete-state view, exact for grids
  and levels), plus its length, mean state and final state;
- ``boosted_profiles``: gradient boosting on the trajectory's profile (:mod:`.profile`: action
  frequencies, state quantiles, state means given each action, length, return): the view that
  holds for continuous states, many features and every-episode-a-new-task games, where a bag
  of exact states sees each state once;
- ``policy_likelihood``: k policies pi_c(a | s) (``policy_mix``'s network) fitted to the training
  folds' styles; a test trajectory goes to the style under whose policy its actions are most
  likely. The supervised form of ``policy_mix``: without it that label-free method beat the
  other two by 5 points on two zoo games (cartpole, mujoco_pendulum; docs/zoo.md);
- ``policy_time_likelihood``: the same with the policies also seeing the time step
  (``clustering.policy_time``), the supervised form of the policy_mix that ``bag_auto`` may keep.

A single model under-reports what the labels allow on games of another shape (a linear model on
visited states said 0.50 on a 4-d control game where boosting on profiles reaches 0.87), and a
label-free method would then "beat the ceiling". No label-free method should beat the panel's
best by more than noise.

``gap = ceiling - clustering accuracy``: near 0 means the clusterer recovers all the style
information these features hold.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np
from scipy import sparse

from pcpg_dist.dataset import Dataset
from pcpg_dist.stages.clustering.states import row_ids

MAX_VOCAB = 20_000  # at most this many visited states / state-actions kept as features


def _bag(ids: np.ndarray, traj: np.ndarray, n: int) -> sparse.csr_matrix:
    """(n trajectories, vocabulary) binary: which ids each trajectory visits.

    Past :data:`MAX_VOCAB` ids only the most frequent are kept. Where the ids tied at the
    boundary count occur once each, they are all left out: an id of one row is seen by one
    trajectory, so it cannot carry a style from the training folds to a test trajectory, and
    which of them made the cut was an arbitrary order (on MiniDungeons, where most state rows
    occur once, that order moved the ceiling by up to 0.7 points). Ids tied at a larger count
    are left out whole too, unless that would keep under half the cap; then they fill it in id
    order (a fixed function of the rows' content).
    """
    uniq, inv, counts = np.unique(ids, return_inverse=True, return_counts=True)
    keep = np.argsort(-counts, kind="stable")
    if len(keep) > MAX_VOCAB:
        boundary = counts[keep[MAX_VOCAB]]
        whole = keep[counts[keep] > boundary]
        keep = whole if boundary == 1 or len(whole) >= MAX_VOCAB // 2 else keep[:MAX_VOCAB]
    col = np.full(len(uniq), -1)
    col[keep] = np.arange(len(keep))
    c = col[inv.reshape(-1)]
    ok = c >= 0
    m = sparse.csr_matrix((np.ones(ok.sum()), (traj[ok], c[ok])), shape=(n, len(keep)))
    m.data[:] = 1.0  # visited or not
    return m


def ceiling_features(ds: Dataset) -> sparse.csr_matrix:
    """The documented feature matrix (see the module doc), one row per trajectory."""
    n = ds.n_trajectories
    traj = ds.row_trajectory
    state_id, _ = row_ids(ds.states)
    sa_id = state_id * (ds.n_actions + 1) + (ds.actions + 1)
    step = ds.actions >= 0
    visits = _bag(state_id, traj, n)
    pairs = _bag(sa_id[step], traj[step], n)
    mean = np.add.reduceat(ds.states.astype(np.float64), ds.offsets[:-1]) / ds.lengths[:, None]
    final = ds.states[ds.offsets[1:] - 1].astype(np.float64)
    dense = np.column_stack([np.log(ds.lengths), mean, final])
    std = dense.std(axis=0)
    dense = (dense - dense.mean(axis=0)) / np.where(std > 1e-9, std, 1.0)
    return sparse.hstack([visits, pairs, sparse.csr_matrix(dense)], format="csr")


def gap_to_ceiling(ceiling: float, accuracy: float) -> float:
    """``ceiling - accuracy``. Both are fractions of whole trajectories (a cross-validated mean
    and a count over n), so a difference under 1e-12 is float noise: it is 0.0, never -0.0, which
    tables would print as "-0.000" ("above the ceiling")."""
    return round(ceiling - accuracy, 12) + 0.0


#: at most this many trajectories (a stratified, seeded sample) are used to estimate the ceiling:
#: its cross-validated accuracy is settled long before, and the boosted model's cost grows with n
MAX_CEILING_TRAJECTORIES = 5000


def _linear_on_bags(ds: Dataset, seed: int):
    from sklearn.linear_model import LogisticRegression

    return ceiling_features(ds), LogisticRegression(C=1.0, max_iter=2000)


def _boosted_on_profiles(ds: Dataset, seed: int):
    from sklearn.ensemble import HistGradientBoostingClassifier

    from pcpg_dist.stages.clustering.profile import trajectory_profiles

    model = HistGradientBoostingClassifier(max_iter=200, early_stopping=False, random_state=seed)
    return trajectory_profiles(ds), model


def _policy_likelihood(
    ds: Dataset, cv, seed: int, time: bool = False, steps: int = 0, hidden: int = 0
) -> float:
    """Cross-validated accuracy of the policy classifier (module doc): for every fold at once
    (batched matrix products, one network a fold), :data:`POLICY_STEPS` Adam steps on minibatches
    of :data:`POLICY_BATCH` training rows, or as many as the smallest fold trains on where that is
    fewer (a cost bounded whatever the log's size, and small for a small log), of the log
    likelihood of each row's action under its style's head; then each test trajectory goes to
    the head with the largest summed log likelihood plus log style share. ``steps`` and
    ``hidden`` (0: :data:`POLICY_STEPS`, :data:`POLICY_HIDDEN`) vary its budget
    (``benchmarks/zoo/policy_class_exp.py``)."""
    import torch

    from pcpg_dist.stages.clustering.policy_network import (
        picked_log_probs,
        policy_inputs,
        policy_states,
    )
    from pcpg_dist.stages.clustering.states import checked_sequences, fit_normaliser

    states, offsets = checked_sequences(ds, "clustering/ceiling")
    n, y = len(offsets) - 1, np.asarray(ds.styles, np.int64)
    k, n_actions = int(y.max()) + 1, int(ds.n_actions)
    if k * n_actions > POLICY_MAX_OUTPUTS:  # its output layer, and its cost, grow with both
        return float("nan")
    seen = policy_states(ds, states, time)
    s, a, valid, traj = policy_inputs(ds, seen, *fit_normaliser(seen))
    if not len(a):
        return float("nan")
    folds = list(cv.split(np.zeros(n), y))
    gen = torch.Generator().manual_seed(seed)
    steps, hidden = steps or POLICY_STEPS, hidden or POLICY_HIDDEN
    sizes = [(s.shape[1], hidden), (hidden, hidden), (hidden, k * n_actions)]
    params = []  # per layer (weight (F, in, out), bias (F, 1, out)), PyTorch's default init
    for fan_in, fan_out in sizes:
        bound = 1.0 / np.sqrt(fan_in)
        for shape in ((len(folds), fan_in, fan_out), (len(folds), 1, fan_out)):
            w = torch.rand(shape, generator=gen) * (2 * bound) - bound
            params.append(w.requires_grad_())

    def log_probs(x, acts, ok, f=slice(None)):
        """(F, B, k): log pi_c(a | s) of rows (F, B, ...) under every head of fold f's networks."""
        h = x
        for i in range(0, len(params), 2):
            h = torch.baddbmm(params[i + 1][f], h, params[i][f])
            h = torch.tanh(h) if i < len(params) - 2 else h
        flat = h.shape[0] * h.shape[1]  # every fold's rows, one after the other
        picked = picked_log_probs(
            h.reshape(flat, k, n_actions), acts.reshape(flat), ok.reshape(flat, n_actions)
        )
        return picked.view(*h.shape[:2], k)

    trained = [torch.from_numpy(np.isin(traj.numpy(), tr)).nonzero()[:, 0] for tr, _ in folds]
    batch = min(POLICY_BATCH, min(len(r) for r in trained))  # a small log: about its own size
    own = torch.from_numpy(y)[traj]
    opt = torch.optim.Adam(params, lr=0.01)
    for _ in range(steps):
        rows = torch.stack([r[torch.randint(0, len(r), (batch,), generator=gen)] for r in trained])
        lp = log_probs(s[rows], a[rows], valid[rows]).gather(2, own[rows][..., None])[..., 0]
        loss = -lp.mean(dim=1).sum()
        opt.zero_grad()
        loss.backward()
        opt.step()
    accuracies = []
    with torch.no_grad():
        for f, (train, test) in enumerate(folds):
            rows = torch.from_numpy(np.isin(traj.numpy(), test)).nonzero()[:, 0]
            lp = log_probs(s[rows][None], a[rows][None], valid[rows][None], slice(f, f + 1))[0]
            scores = torch.zeros(k, n).index_add_(1, traj[rows], lp.T)
            share = np.bincount(y[train], minlength=k) / len(train)
            scores += torch.from_numpy(np.log(np.maximum(share, 1e-12))).float()[:, None]
            accuracies.append(float((scores[:, test].argmax(0).numpy() == y[test]).mean()))
    return float(np.mean(accuracies))


POLICY_STEPS = 300  # Adam steps of the policy classifier (all folds at once)
POLICY_HIDDEN = 32  # its two tanh layers, as policy_mix's network
#: left out above this many styles x actions (a 1,000-action log took minutes; the zoo's largest
#: below it is 4 x 9 = 36, and chess's 4 x 4,672 is left out)
POLICY_MAX_OUTPUTS = 512
POLICY_BATCH = 4096  # training rows a fold and step (sampled with replacement, seeded)


def _cross_validated(make):
    """A (features, sklearn model) member as a ``(ds, cv, seed) -> accuracy`` one."""

    def score(ds: Dataset, cv, seed: int) -> float:
        from sklearn.model_selection import cross_val_score

        x, model = make(ds, seed)
        return float(cross_val_score(model, x, ds.styles, cv=cv, n_jobs=1).mean())

    return score


#: the supervised panel: name -> its cross-validated accuracy on a dataset given the true styles.
#: The ceiling is the best of them, each 5-fold cross-validated (docs/clustering.md, "The ceiling")
PANEL = {
    "linear_bags": _cross_validated(_linear_on_bags),
    "boosted_profiles": _cross_validated(_boosted_on_profiles),
    "policy_likelihood": _policy_likelihood,
    "policy_time_likelihood": functools.partial(_policy_likelihood, time=True),
}


def _labelled_sample(ds: Dataset, seed: int) -> Dataset | None:
    """The dataset (or a stratified sample of MAX_CEILING_TRAJECTORIES of it) when every
    trajectory has a style and at least two styles have two trajectories; else None."""
    y = ds.styles
    if not len(y) or (y < 0).any():
        return None
    counts = np.bincount(y)
    if (counts > 1).sum() < 2:
        return None
    if len(y) <= MAX_CEILING_TRAJECTORIES:
        return ds
    from sklearn.model_selection import train_test_split

    keep, _ = train_test_split(
        np.arange(len(y)), train_size=MAX_CEILING_TRAJECTORIES, stratify=y, random_state=seed
    )
    return ds.subset(np.sort(keep))


def ceiling_panel(
    ds: Dataset, seed: int = 0, folds: int = 5, move_features: str | None = None
) -> dict[str, float]:
    """Each panel model's cross-validated accuracy given the true styles ({} without them).
    With ``move_features`` (``clustering.move_features``) the panel also has
    ``choice_likelihood``, the supervised form of ``choice_mix``: one choice model per style over
    what each legal move does."""
    from sklearn.model_selection import StratifiedKFold
    from threadpoolctl import threadpool_limits

    ds = _labelled_sample(ds, seed)
    if ds is None:
        return {}
    counts = np.bincount(ds.styles)
    k = int(min(folds, counts[counts > 0].min()))
    if k < 2:
        return {}
    cv = StratifiedKFold(n_splits=k, shuffle=True, random_state=seed)
    scores = {}
    # one thread, as the task that computes it was given (OpenMP in the boosted model)
    with warnings.catch_warnings(), threadpool_limits(1):
        warnings.simplefilter("ignore")  # convergence chatter on separable data
        for name, member in PANEL.items():
            score = member(ds, cv, seed)
            if np.isfinite(score):
                scores[name] = score
        if move_features is not None:
            from pcpg_dist.stages.clustering.choice_mix import supervised_accuracy
            from pcpg_dist.stages.clustering.move_pairs import load_move_features, pairs_of

            pairs = pairs_of(ds, load_move_features(move_features), move_features)
            scores["choice_likelihood"] = supervised_accuracy(pairs, ds.styles, cv)
    return scores


def supervised_ceiling(ds: Dataset, seed: int = 0, folds: int = 5) -> float:
    """The best cross-validated accuracy of the panel's models given the true styles (NaN
    without them)."""
    scores = ceiling_panel(ds, seed, folds)
    return max(scores.values()) if scores else float("nan")
