"""Pong (Atari 2600 via ale-py, ``ALE/Pong-v5`` with RAM observations): four paddle controllers
playing the built-in opponent.

States are the console's 128 RAM bytes. The controllers read the right paddle's y (RAM 51), the
ball's x and y (RAM 49, 54); they differ in where and how they move the paddle. Actions: 0 stay
(NOOP), 1 up (RIGHT), 2 down (LEFT). v5's sticky actions (the previous action repeats with
probability 0.25 each frame) stay on. An episode ends when either side reaches ``POINTS`` points
or after ``MAX_STEPS`` agent steps (frameskip 4), so lengths vary from hundreds to thousands.
Per-episode noise: each controller's aim offset, dead zone and gains are drawn around its own
centre, and it takes a random action with a small probability.
"""

from __future__ import annotations

from collections.abc import Callable

import ale_py
import gymnasium as gym
import numpy as np

from benchmarks.zoo.common import Episode, Game

gym.register_envs(ale_py)

ENV = "ALE/Pong-v5"
ENV_ACTIONS = (0, 2, 3)  # our 0 stay, 1 up, 2 down -> NOOP, RIGHT, LEFT
PLAYER_Y, BALL_X, BALL_Y = 51, 49, 54
PADDLE_X, TOP, BOTTOM = 188, 38, 203  # where the ball meets our paddle; the ball's y range
POINTS, MAX_STEPS = 5, 2000

STYLES = (
    "tight tracker: follows the ball's y closely",
    "predictive: waits at the predicted intercept",
    "lazy: moves only when far off",
    "jittery: alternates up/down near the ball",
)


def _toward(d: float, dead: float) -> int:
    """Our action moving the paddle by d (positive: down), or staying within the dead zone."""
    if abs(d) < dead:
        return 0
    return 2 if d > 0 else 1


def _intercept(bx: int, by: int, vx: int, vy: int) -> float:
    """The ball's y when it reaches our paddle, bouncing off the top and bottom walls."""
    y = by + vy * (PADDLE_X - bx) / vx
    span = BOTTOM - TOP
    y = (y - TOP) % (2 * span)
    return TOP + (y if y <= span else 2 * span - y)


def _policy(style: int, rng: np.random.Generator) -> Callable[[np.ndarray, np.ndarray], int]:
    off = rng.normal(8.0, 1.5)  # where on the paddle (from its top) the ball should land
    if style == 0:
        lead, dead = rng.normal(1.0, 0.3), rng.uniform(2.0, 9.0)

        def tight(ram, prev):
            by, vy = ram[BALL_Y], ram[BALL_Y] - prev[BALL_Y]
            return _toward(by + lead * vy - ram[PLAYER_Y] - off, dead)

        return tight
    if style == 1:
        dead, rest = rng.uniform(2.0, 5.0), rng.normal(120.0, 10.0)

        def predictive(ram, prev):
            bx, by = ram[BALL_X], ram[BALL_Y]
            vx, vy = bx - prev[BALL_X], by - prev[BALL_Y]
            target = _intercept(bx, by, vx, vy) if vx > 0 and bx and prev[BALL_X] else rest
            return _toward(target - ram[PLAYER_Y] - off, dead)

        return predictive
    if style == 2:
        far = rng.uniform(7.0, 18.0)

        def lazy(ram, prev):
            return _toward(ram[BALL_Y] - ram[PLAYER_Y] - off, far)

        return lazy
    near, jitter, flip = rng.uniform(5.0, 14.0), rng.uniform(0.3, 0.9), [1]

    def jittery(ram, prev):
        d = ram[BALL_Y] - ram[PLAYER_Y] - off
        if abs(d) < near and rng.random() < jitter:
            flip[0] = 3 - flip[0]
            return flip[0]
        return _toward(d, 3.0)

    return jittery


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    env = gym.make(ENV, obs_type="ram", disable_env_checker=True)
    ram, _ = env.reset(seed=seed)
    policy, eps = _policy(style, rng), rng.uniform(0.02, 0.1)
    ram = prev = ram.astype(np.int64)
    states, actions, rewards = [ram], [], []
    won = lost = 0
    while won < POINTS and lost < POINTS and len(actions) < MAX_STEPS:
        a = int(rng.integers(3)) if rng.random() < eps else policy(ram, prev)
        prev = ram
        ram, r, terminated, truncated, _ = env.step(ENV_ACTIONS[a])
        ram = ram.astype(np.int64)
        states.append(ram)
        actions.append(a)
        rewards.append(r)
        won, lost = won + (r > 0), lost + (r < 0)
        if terminated or truncated:
            break
    env.close()
    return Episode(np.array(states), np.array(actions), np.array(rewards))


GAME = Game(
    name="pong",
    package="ale-py (Atari 2600, ALE/Pong-v5, RAM observations)",
    kinds=("variable lengths up to thousands of steps", "RAM observations"),
    styles=STYLES,
    counts=(28, 24, 24, 18),
    ci_counts=(7, 6, 6, 5),
    n_actions=3,
    play=play,
)
