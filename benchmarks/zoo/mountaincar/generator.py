"""MountainCar-v0 (Gymnasium classic control): three ways of swinging an underpowered car up.

Continuous 2-d states (position, velocity), three actions (push left, no push, push right),
episodes up to 200 steps, reward -1 a step until the flag. Every style builds up energy by
pushing with the car's motion, differently: at once on the velocity's sign, after first rocking
back up the left slope, or on the velocity seen a few steps late while coasting when slow. Per
episode the rock-back length, the delay and the coasting threshold are drawn, and a random action
is taken with a small probability.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from benchmarks.zoo.common import Episode, Game, record

STYLES = (
    "push with the velocity's sign",
    "rock back up the left slope first, then pump",
    "delayed pumping, coasting when slow",
)


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    rock = int(rng.integers(15, 35))  # style 1: steps pushing left before pumping
    delay = int(rng.integers(1, 4))  # style 2: how late it sees the velocity
    coast = rng.uniform(0.0005, 0.002)  # style 2: no push below this speed
    eps = rng.uniform(0.02, 0.08)
    env = gym.make("MountainCar-v0")
    obs, _ = env.reset(seed=seed)

    def act(obs, states) -> int:
        t, vel = len(states) - 1, float(obs[1])
        if style == 1 and t < rock:
            a = 0
        elif style == 2:
            seen = float(states[max(0, t - delay)][1])
            a = 1 if abs(seen) < coast else (2 if seen > 0 else 0)
        else:
            a = 2 if vel >= 0 else 0
        if rng.random() < eps:
            a = int(rng.integers(3))
        return a

    return record(env, obs, act)


GAME = Game(
    name="mountaincar",
    package="gymnasium (classic control)",
    kinds=("continuous low-dimensional states", "fixed task", "unequal style counts"),
    styles=STYLES,
    counts=(200, 140, 100),
    ci_counts=(50, 35, 25),
    n_actions=3,
    play=play,
    gymnasium_env="MountainCar-v0",
)
