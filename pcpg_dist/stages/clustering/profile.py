"""A trajectory's profile: fixed-size summary features any game's trajectory shows its style in,
whatever the shape of its states (discrete cells, continuous control, RAM bytes, many features).

Per trajectory, with ``d`` state features and ``n`` actions:
- action frequencies (``n``): how often each action was taken;
- action switches (1): how often consecutive actions differ (jittery or steady play);
- state quantiles (``3 d``): the 10th, 50th and 90th percentile of each state feature;
- state means given each action (``n d``): where each action was taken (a policy's signature),
  the trajectory's mean state where it never took the action;
- length and return (2, log-scaled where they span orders of magnitude).

State features with one value throughout the data carry nothing and are left out first; with
many features (RAM bytes) only the ``MAX_FEATURES`` with the largest spread across trajectories
are kept, and with many actions (chess's 4,672 move ids) only the ``MAX_ACTIONS`` taken most
often over the log have their own frequency and means (the others share one frequency column),
so the profile stays a few thousand columns at most.
"""

from __future__ import annotations

import numpy as np

from pcpg_dist.dataset import Dataset

MAX_FEATURES = 48  # state features kept for the quantiles and the per-action means
MAX_ACTIONS = 64  # actions with their own columns (the most taken); every built-in domain has fewer
QUANTILES = (0.1, 0.5, 0.9)


def _kept_features(ds: Dataset) -> np.ndarray:
    """Indices of the state features the profile uses: varying ones, at most MAX_FEATURES (those
    whose per-trajectory means differ most, relative to their overall spread)."""
    states = ds.states
    spread = states.std(axis=0)
    varying = np.nonzero(spread > 1e-9)[0]
    if len(varying) <= MAX_FEATURES:
        return varying
    traj = ds.row_trajectory
    counts = np.bincount(traj, minlength=ds.n_trajectories)[:, None]
    means = np.zeros((ds.n_trajectories, len(varying)))
    np.add.at(means, traj, states[:, varying])
    means /= np.maximum(counts, 1)
    between = means.std(axis=0) / spread[varying]
    order = np.argsort(-between, kind="stable")[:MAX_FEATURES]
    return np.sort(varying[order])


def _kept_actions(actions: np.ndarray, steps: np.ndarray, n_actions: int):
    """(actions, columns): every action its own column, or, with more than ``MAX_ACTIONS``, the
    ``MAX_ACTIONS`` taken most often renumbered 0.. in that order and every other one pooled as
    ``MAX_ACTIONS`` (columns ``MAX_ACTIONS + 1``)."""
    if n_actions <= MAX_ACTIONS:
        return actions, n_actions
    counts = np.bincount(actions[steps], minlength=n_actions)
    order = np.argsort(-counts, kind="stable")
    column = np.full(n_actions, MAX_ACTIONS, np.int64)
    column[order[:MAX_ACTIONS]] = np.arange(MAX_ACTIONS)
    return np.where(steps, column[np.maximum(actions, 0)], actions), MAX_ACTIONS + 1


def trajectory_profiles(ds: Dataset) -> np.ndarray:
    """(trajectories, features) float64: every trajectory's profile (see the module doc)."""
    n_traj = ds.n_trajectories
    keep = _kept_features(ds)
    states = ds.states[:, keep].astype(np.float64)
    d = len(keep)
    steps = ds.actions >= 0
    traj = ds.row_trajectory
    actions, n_act = _kept_actions(ds.actions, steps, ds.n_actions)
    act_counts = np.zeros((n_traj, n_act))
    np.add.at(act_counts, (traj[steps], actions[steps]), 1.0)
    n_steps = np.maximum(act_counts.sum(axis=1, keepdims=True), 1.0)
    freq = act_counts / n_steps
    switches = np.zeros(n_traj)
    same_traj = traj[1:] == traj[:-1]
    changed = same_traj & steps[1:] & steps[:-1] & (ds.actions[1:] != ds.actions[:-1])
    np.add.at(switches, traj[1:][changed], 1.0)
    switches /= n_steps[:, 0]
    quant = np.zeros((n_traj, len(QUANTILES) * d))
    mean_state = np.zeros((n_traj, d))
    for i in range(n_traj):
        rows = states[ds.offsets[i] : ds.offsets[i + 1]]
        quant[i] = np.quantile(rows, QUANTILES, axis=0).reshape(-1) if d else quant[i]
        mean_state[i] = rows.mean(axis=0) if d else mean_state[i]
    n_own = min(n_act, MAX_ACTIONS)  # the pooled column, where there is one, has no means
    own = steps & (actions < n_own)
    given = np.zeros((n_traj, n_own, d))
    np.add.at(given, (traj[own], actions[own]), states[own])
    taken = act_counts[:, :n_own, None]
    given = np.where(taken > 0, given / np.maximum(taken, 1.0), mean_state[:, None, :])
    lengths = np.log1p(ds.lengths.astype(np.float64))
    returns = ds.returns.astype(np.float64)
    signed_log = np.sign(returns) * np.log1p(np.abs(returns))
    return np.column_stack([freq, switches, quant, given.reshape(n_traj, -1), lengths, signed_log])
