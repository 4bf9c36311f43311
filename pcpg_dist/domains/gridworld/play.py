"""Playing a GridWorld layout: rollouts of a policy, the returns of trajectories, a drawing.

These are the domain's hooks (:class:`~pcpg_dist.domains.base.DomainHooks`): the evaluation plays
the trained agents here, scores their trajectories under each style's reward and draws them. They
read the layout's tables (:class:`~pcpg_dist.domains.gridworld.layout.GridTables`), so a rollout
of many episodes is a few array operations per step.
"""

from __future__ import annotations

import numpy as np

from pcpg_dist.dataset import Dataset
from pcpg_dist.domains.base import Policy
from pcpg_dist.domains.gridworld.layout import FEATURES, N_ACTIONS, REWARDS, Layout


def rollout(
    layout: Layout,
    policy: Policy,
    n_episodes: int,
    rng: np.random.Generator,
    max_steps: int = 100,
    reward_index: int = 0,
) -> Dataset:
    """Roll ``policy`` out ``n_episodes`` times from S, all episodes stepped together.

    The returned Dataset's rewards are under R_{reward_index + 1}; ``success`` = reached G.
    """
    t = layout.tables
    s = np.full(n_episodes, t.start, np.int64)
    states, actions = [s.copy()], []
    alive = np.ones(n_episodes, bool)
    lengths = np.ones(n_episodes, np.int64)
    for _ in range(max_steps):
        live = np.nonzero(alive)[0]
        if not len(live):
            break
        a = np.asarray(policy(t.features[s[live]], t.valid[s[live]], rng), np.int64)
        if not t.valid[s[live], a].all():
            raise ValueError("policy returned an invalid action")
        act = np.full(n_episodes, -1, np.int64)
        act[live] = a
        s = s.copy()
        s[live] = t.next_state[s[live], a]
        actions.append(act)
        states.append(s.copy())
        lengths[live] += 1
        alive &= ~t.terminal[s]
    trajs = []
    st, ac = (
        np.stack(states, 1),
        np.stack(actions, 1) if actions else np.zeros((n_episodes, 0), np.int64),
    )
    for i in range(n_episodes):
        seq, acts = st[i, : lengths[i]], ac[i, : lengths[i] - 1]
        trajs.append(
            {
                "states": t.features[seq],
                "actions": acts,
                "valid": t.valid[seq],
                "rewards": t.reward[reward_index, seq[:-1], acts],
            }
        )
    success = [bool(t.goal[st[i, lengths[i] - 1]]) for i in range(n_episodes)]
    return Dataset.from_trajectories(
        "gridworld",
        layout.name,
        N_ACTIONS,
        trajs,
        styles=[-1] * n_episodes,
        success=success,
        feature_names=FEATURES,
    )


def returns(dataset: Dataset, reward_index: int) -> np.ndarray:
    """Undiscounted return of every trajectory under R_{reward_index + 1}, from its final state."""
    last = dataset.states[dataset.offsets[1:] - 1]
    g, r1, r2 = REWARDS[reward_index]
    return g * dataset.success + r1 * last[:, 2] + r2 * last[:, 3]


def draw_trajectory(ax, layout: Layout, dataset: Dataset, title: str | None = None) -> None:
    """Draw the grid and the (first) trajectory of ``dataset`` on a matplotlib axis (Fig. 8)."""
    colours = {
        ".": (1, 1, 1),
        "#": (0.25, 0.25, 0.25),
        "S": (0.6, 0.8, 1.0),
        "G": (0.4, 0.85, 0.4),
        "X": (0.95, 0.4, 0.4),
        "1": (1.0, 0.85, 0.3),
        "2": (0.85, 0.55, 1.0),
    }
    img = np.array([[colours[c] for c in row] for row in layout.grid])
    ax.imshow(img, origin="upper")
    for ch in "SG12X":
        for x, y in layout.find(ch):
            ax.text(x, y, {"1": "B1", "2": "B2"}.get(ch, ch), ha="center", va="center", fontsize=7)
    if dataset.n_trajectories:
        xy = dataset.trajectory_states(0)[:, :2]
        jitter = np.linspace(-0.15, 0.15, len(xy))
        ax.plot(
            xy[:, 0] + jitter, xy[:, 1] + jitter, "-o", color="navy", markersize=2, linewidth=1.5
        )
    ax.set_xticks([])
    ax.set_yticks([])
    if title:
        ax.set_title(title, fontsize=8)
