"""Freeway (Atari 2600 via ale-py, ``ALE/Freeway-v5`` with RAM observations): four ways of
getting the chicken across ten lanes of traffic.

States are the console's 128 RAM bytes. The controllers read the chicken's height (RAM 14, 6 at
the kerb, rising by about 16 per lane) and the cars' x (RAM 108-117, lane 0 nearest; lanes 0-4
drive right, lanes 5-9 drive left); a car hitting the chicken pushes it back down. Actions are
the env's own: 0 NOOP, 1 UP, 2 DOWN. v5's sticky actions stay on. Every episode is the first half
of a game's timer (``MAX_STEPS`` = 1,024 agent steps at frameskip 4, about 68 s of the 2:16
game), the same length for all; the return is the crossings made.
Per-episode noise: each controller's safety margins and pace are drawn around its own centre,
and it takes a random action with a small probability.
"""

from __future__ import annotations

from collections.abc import Callable

import ale_py
import gymnasium as gym
import numpy as np

from benchmarks.zoo.common import Episode, Game

gym.register_envs(ale_py)

ENV = "ALE/Freeway-v5"
CHICKEN_Y, CARS = 14, slice(108, 118)
CHICKEN_X, LANE0_Y, LANE_H, WIDTH = 44, 16, 16, 160
MAX_STEPS = 1024  # the first half of the game's 2:16 timer

STYLES = (
    "rush: always up",
    "gap-waiter: waits when a car nears the next lane",
    "zigzag: steps back down to dodge",
    "cautious-slow: unhurried, waits for wide gaps",
)


def _arrival(ram: np.ndarray, prev: np.ndarray, lane: int) -> float:
    """Agent steps until lane's car reaches the chicken's column (0 while it is on it)."""
    if not 0 <= lane < 10:
        return np.inf
    x, px = ram[CARS][lane], prev[CARS][lane]
    sign = 1 if lane < 5 else -1  # lanes 0-4 drive right, 5-9 left
    speed = max(((x - px) * sign) % WIDTH, 1) if (x - px) % WIDTH else 1
    ahead = ((CHICKEN_X - x) * sign) % WIDTH  # how far the car still has to drive
    if ahead > WIDTH - 12:  # on the chicken's column or just past it
        return 0.0
    return ahead / speed


def _next_lane(y: int) -> int:
    return int(np.floor((y - LANE0_Y) / LANE_H + 1.0))


def _policy(style: int, rng: np.random.Generator) -> Callable[[np.ndarray, np.ndarray], int]:
    if style == 0:
        return lambda ram, prev: 1
    if style == 1:
        wait = rng.normal(5.0, 0.8)

        def gap_waiter(ram, prev):
            return 0 if _arrival(ram, prev, _next_lane(ram[CHICKEN_Y])) < wait else 1

        return gap_waiter
    if style == 2:
        danger = rng.normal(3.0, 0.5)

        def zigzag(ram, prev):
            lane = _next_lane(ram[CHICKEN_Y])
            here = _arrival(ram, prev, lane - 1)  # the lane the chicken stands in
            if _arrival(ram, prev, lane) < danger or here < danger:
                return 2
            return 1

        return zigzag
    wait, pace = rng.normal(7.0, 0.8), rng.uniform(0.7, 0.85)

    def cautious(ram, prev):
        lane = _next_lane(ram[CHICKEN_Y])
        if min(_arrival(ram, prev, lane), _arrival(ram, prev, lane + 1) + 3) < wait:
            return 0
        return 1 if rng.random() < pace else 0

    return cautious


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    env = gym.make(ENV, obs_type="ram", disable_env_checker=True)
    ram, _ = env.reset(seed=seed)
    policy, eps = _policy(style, rng), rng.uniform(0.02, 0.08)
    ram = prev = ram.astype(np.int64)
    states, actions, rewards = [ram], [], []
    done = False
    while not done and len(actions) < MAX_STEPS:
        a = int(rng.integers(3)) if rng.random() < eps else policy(ram, prev)
        prev = ram
        ram, r, terminated, truncated, _ = env.step(a)
        ram = ram.astype(np.int64)
        states.append(ram)
        actions.append(a)
        rewards.append(r)
        done = terminated or truncated
    env.close()
    return Episode(np.array(states), np.array(actions), np.array(rewards))


GAME = Game(
    name="freeway",
    package="ale-py (Atari 2600, ALE/Freeway-v5, RAM observations)",
    kinds=("RAM observations", "long fixed-length episodes"),
    styles=STYLES,
    counts=(20, 16, 16, 12),
    ci_counts=(5, 4, 4, 3),
    n_actions=3,
    play=play,
    gymnasium_env=ENV,
    gymnasium_kwargs={"obs_type": "ram"},
)
