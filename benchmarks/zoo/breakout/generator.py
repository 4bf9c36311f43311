"""Breakout (Atari 2600 via ale-py, ``ALE/Breakout-v5`` with RAM observations): three paddle
controllers clearing bricks. A held-out game: no clusterer design decision looks at it.

States are the console's 128 RAM bytes. The controllers read the paddle's x (RAM 72), the ball's
x and y (RAM 99, 101; y is 0 while no ball is in play) and launch a new ball with FIRE. Actions
are the env's own: 0 NOOP, 1 FIRE, 2 RIGHT, 3 LEFT. v5's sticky actions stay on. An episode ends
when the five lives are lost or after ``MAX_STEPS`` agent steps (frameskip 4). Per-episode noise:
each controller's aim, lead and dead zone are drawn around its own centre, and it takes a random
action with a small probability.
"""

from __future__ import annotations

from collections.abc import Callable

import ale_py
import gymnasium as gym
import numpy as np

from benchmarks.zoo.common import Episode, Game

gym.register_envs(ale_py)

ENV = "ALE/Breakout-v5"
PADDLE_X, BALL_X, BALL_Y = 72, 99, 101
CENTRE, AIM = 7, 123  # ball x minus paddle x when centred; the paddle's x mid-screen
MAX_STEPS = 1500

STYLES = (
    "centre-hugger: waits mid-screen until the ball comes low",
    "ball-follower: keeps the paddle under the ball",
    "edge-aimer: meets the ball with one edge of the paddle",
)


def _toward(d: float, dead: float) -> int:
    """Our action moving the paddle by d (positive: right), or staying within the dead zone."""
    if abs(d) < dead:
        return 0
    return 2 if d > 0 else 3


def _policy(style: int, rng: np.random.Generator) -> Callable[[np.ndarray, np.ndarray], int]:
    dead, lead = rng.uniform(2.0, 4.0), rng.normal(1.0, 0.3)
    if style == 0:
        low, home = rng.normal(140.0, 10.0), AIM + rng.normal(0.0, 6.0)

        def hugger(ram, prev):
            bx, by = ram[BALL_X], ram[BALL_Y]
            if by < low or by < prev[BALL_Y] or not prev[BALL_Y]:  # high, or going up
                return _toward(home - ram[PADDLE_X], dead + 3)
            return _toward(bx + lead * (bx - prev[BALL_X]) - CENTRE - ram[PADDLE_X], dead)

        return hugger
    edge = rng.choice([-1.0, 1.0]) * rng.uniform(4.0, 6.0) if style == 2 else 0.0

    def follower(ram, prev):
        bx = ram[BALL_X]
        vx = bx - prev[BALL_X] if prev[BALL_Y] else 0
        return _toward(bx + lead * vx - CENTRE - edge - ram[PADDLE_X], dead)

    return follower


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    env = gym.make(ENV, obs_type="ram", disable_env_checker=True)
    ram, _ = env.reset(seed=seed)
    policy, eps = _policy(style, rng), rng.uniform(0.02, 0.06)
    ram = prev = ram.astype(np.int64)
    states, actions, rewards = [ram], [], []
    done = False
    while not done and len(actions) < MAX_STEPS:
        if rng.random() < eps:
            a = int(rng.integers(4))
        else:
            a = 1 if ram[BALL_Y] == 0 else policy(ram, prev)
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
    name="breakout",
    package="ale-py (Atari 2600, ALE/Breakout-v5, RAM observations)",
    kinds=("RAM observations", "held-out game", "variable lengths"),
    styles=STYLES,
    counts=(40, 32, 28),
    ci_counts=(8, 8, 7),
    n_actions=4,
    play=play,
    gymnasium_env=ENV,
    gymnasium_kwargs={"obs_type": "ram"},
    held_out=True,
)
