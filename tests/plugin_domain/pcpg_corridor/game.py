"""The corridor game: one row of cells, two coins, an exit, and three scripted play-styles.

    cell   0   1   2   3   4   5   6   7   8   9  10  11      (length 12)
               c       c       S                       E

The player starts on S (the middle cell); the exit E is the rightmost cell and ends the episode.
Two coins lie left of the start, 2 and 4 cells away.

Actions: ``LEFT`` (invalid on cell 0), ``RIGHT``, ``TAKE`` (valid only on a coin not yet taken).

State (4 floats, all a player sees): ``position`` = cell / (length - 1); ``coin_near_taken`` and
``coin_far_taken`` (0 or 1); ``left_end_seen`` (1 once the player has stood on cell 0).

Reward: +0.5 for taking a coin, +1 for reaching the exit, 0 otherwise.

Episode end: the exit is reached (success) or ``max_steps`` actions were taken (failure).

Play-styles (scripted; each decides from the state alone):

- ``rusher``: straight to the exit.
- ``collector``: walks left taking both coins, then to the exit.
- ``explorer``: walks to the left end (ignoring the coins), then to the exit.

Each trajectory has its own noise level epsilon: at every step, with probability epsilon, the
player takes a uniformly random valid action instead, so trajectories of one style differ in skill.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from pcpg_dist.domains.base import Policy, random_policy

if TYPE_CHECKING:  # pyarrow comes with it: imported when data is made, not when a config loads
    from pcpg_dist.dataset import Dataset

LEFT, RIGHT, TAKE = 0, 1, 2
ACTION_NAMES = ("left", "right", "take")
FEATURE_NAMES = ("position", "coin_near_taken", "coin_far_taken", "left_end_seen")
STYLES = ("rusher", "collector", "explorer")
RUSHER, COLLECTOR, EXPLORER = range(3)
COIN_REWARD, EXIT_REWARD = 0.5, 1.0
MIN_LENGTH = 10  # the far coin (start - 4) must lie right of cell 0


@dataclass(frozen=True)
class Corridor:
    """The level: its length fixes the start, the coins and the exit."""

    length: int

    def __post_init__(self) -> None:
        if self.length < MIN_LENGTH:
            raise ValueError(f"a corridor needs at least {MIN_LENGTH} cells, got {self.length}")

    @property
    def start(self) -> int:
        return self.length // 2

    @property
    def exit(self) -> int:
        return self.length - 1

    @property
    def coins(self) -> np.ndarray:
        """Cells of the near and the far coin."""
        return np.array([self.start - 2, self.start - 4])

    def route_length(self, style: int) -> int:
        """Actions the noiseless ``style`` takes from start to exit."""
        right = self.exit - self.start
        # the collector walks 4 cells left, takes 2 coins and walks the 4 cells back
        return {RUSHER: right, COLLECTOR: 4 + 2 + 4 + right, EXPLORER: self.start + self.exit}[
            style
        ]

    def observe(
        self, pos: np.ndarray, taken: np.ndarray, seen: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """States (B, 4) float32 and valid masks (B, 3) bool of B players."""
        states = np.column_stack([pos / (self.length - 1), taken, seen]).astype(np.float32)
        on_coin = (pos[:, None] == self.coins) & ~taken
        valid = np.column_stack([pos > 0, np.ones(len(pos), bool), on_coin.any(axis=1)])
        return states, valid


def scripted(corridor: Corridor, style: int) -> Policy:
    """The noiseless policy of one play-style (a batched :data:`Policy`)."""

    def act(states: np.ndarray, valid: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        pos = np.rint(states[:, 0] * (corridor.length - 1)).astype(np.int64)
        taken, seen = states[:, 1:3] > 0.5, states[:, 3] > 0.5
        if style == RUSHER:
            return np.full(len(states), RIGHT)
        if style == COLLECTOR:  # take a coin underfoot, walk to one left of us, else leave
            coin_left = ((corridor.coins < pos[:, None]) & ~taken).any(axis=1)
            return np.where(valid[:, TAKE], TAKE, np.where(coin_left, LEFT, RIGHT))
        return np.where(seen, RIGHT, LEFT)  # explorer: the left end first

    return act


def play(
    corridor: Corridor,
    policy: Policy,
    n_episodes: int,
    rng: np.random.Generator,
    max_steps: int,
    epsilon: np.ndarray | None = None,
    style: int = -1,
) -> Dataset:
    """``n_episodes`` episodes of ``policy``, all stepped together, as a Dataset.

    ``epsilon`` (one per episode) replaces each action by a random valid one with that
    probability; ``style`` labels every trajectory (-1 = unknown, as for a trained agent).
    """
    from pcpg_dist.dataset import Dataset

    n = n_episodes
    pos = np.full(n, corridor.start)
    taken = np.zeros((n, 2), bool)
    seen = np.zeros(n, bool)
    alive = np.ones(n, bool)
    states, valid = corridor.observe(pos, taken, seen)
    trace_s, trace_v, trace_a, trace_r = [states], [valid], [], []
    lengths = np.ones(n, np.int64)
    for _ in range(max_steps):
        live = np.nonzero(alive)[0]
        if not len(live):
            break
        s, v = states[live], valid[live]
        a = np.asarray(policy(s, v, rng), np.int64)
        if epsilon is not None:
            noisy = rng.random(len(live)) < epsilon[live]
            a[noisy] = random_policy(s[noisy], v[noisy], rng)
        if not v[np.arange(len(live)), a].all():
            raise ValueError("policy returned an invalid action")
        action, reward = np.full(n, -1), np.zeros(n)
        action[live] = a
        pos = pos.copy()
        pos[live] += np.select([a == LEFT, a == RIGHT], [-1, 1], 0)
        picked = (a == TAKE)[:, None] & (pos[live, None] == corridor.coins)
        taken[live] |= picked
        seen |= pos == 0
        reward[live] = COIN_REWARD * picked.any(axis=1) + EXIT_REWARD * (pos[live] == corridor.exit)
        lengths[live] += 1
        alive &= pos != corridor.exit
        states, valid = corridor.observe(pos, taken, seen)
        trace_s.append(states)
        trace_v.append(valid)
        trace_a.append(action)
        trace_r.append(reward)
    st, va = np.stack(trace_s, axis=1), np.stack(trace_v, axis=1)  # (n, steps + 1, ...)
    ac = np.stack(trace_a, axis=1) if trace_a else np.zeros((n, 0), np.int64)
    rw = np.stack(trace_r, axis=1) if trace_r else np.zeros((n, 0))
    trajectories = [
        {
            "states": st[i, :t],
            "actions": ac[i, : t - 1],
            "valid": va[i, :t],
            "rewards": rw[i, : t - 1],
        }
        for i, t in enumerate(lengths)
    ]
    return Dataset.from_trajectories(
        "corridor",
        f"L{corridor.length}",
        len(ACTION_NAMES),
        trajectories,
        styles=[style] * n,
        success=~alive,
        epsilon=epsilon,
        feature_names=FEATURE_NAMES,
        action_names=ACTION_NAMES,
    )


def generate(
    corridor: Corridor, per_style: int, noise_max: float, max_steps: int, seed: int
) -> Dataset:
    """``per_style`` noisy trajectories of every play-style, labelled with their true style."""
    from pcpg_dist.dataset import Dataset

    parts = []
    for style in range(len(STYLES)):
        rng = np.random.default_rng([seed, style])
        epsilon = rng.uniform(0.0, noise_max, per_style)
        parts.append(
            play(
                corridor,
                scripted(corridor, style),
                per_style,
                rng,
                max_steps,
                epsilon=epsilon,
                style=style,
            )
        )
    return Dataset.concat(parts)


def rollout_fn(
    corridor: Corridor, max_steps: int
) -> Callable[[Policy, int, np.random.Generator], Dataset]:
    """What the evaluation calls to roll a trained agent out (``DomainHooks.rollout``)."""
    return lambda policy, n, rng: play(corridor, policy, n, rng, max_steps)
