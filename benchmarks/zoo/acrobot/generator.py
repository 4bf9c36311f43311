"""Acrobot (Gymnasium classic control, ``Acrobot-v1``): four ways of pumping a two-link pendulum
up past the line, written after every design choice of the clusterers (a blind game).

Continuous 6-d states (the env's observation: cos and sin of both joint angles, both angular
velocities); the env's 3 actions (torque -1, 0, +1 on the elbow); an episode ends when the tip
swings above the line (80-250 steps) or at the env's limit of 500. Every controller pumps energy
into the swing, each by its own rule; per episode its gains are drawn around its own centre, and
it takes a random action with a small probability.
"""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np

from benchmarks.zoo.common import Episode, Game, record

NEG, IDLE, POS = 0, 1, 2
STYLES = (
    "elbow pump: torque with the elbow's own swing",
    "shoulder-led pump: torque with the shoulder's swing, helped by the elbow's",
    "gentle pump: the elbow's swing, idle while it is slow",
    "switching: shoulder-led low down, elbow pump once the swing is high",
)


def _policy(style: int, rng: np.random.Generator) -> Callable[[np.ndarray], int]:
    def angles(obs):
        c1, s1, c2, s2, d1, d2 = obs
        return np.arctan2(s1, c1), np.arctan2(s2, c2), d1, d2

    if style == 0:
        lead = rng.uniform(0.0, 0.3)  # a little of the elbow's angle, ahead of its speed
        return lambda obs: (lambda t1, t2, d1, d2: POS if d2 + lead * t2 > 0 else NEG)(*angles(obs))
    if style == 1:
        c = rng.uniform(0.4, 0.9)
        return lambda obs: (lambda t1, t2, d1, d2: POS if d1 + c * d2 > 0 else NEG)(*angles(obs))
    if style == 2:
        dead = rng.uniform(0.15, 0.4)

        def gentle(obs):
            _, _, _, d2 = angles(obs)
            return IDLE if abs(d2) < dead else (POS if d2 > 0 else NEG)

        return gentle
    high, c = rng.uniform(0.6, 1.0), rng.uniform(0.4, 0.7)

    def switching(obs):
        t1, _, d1, d2 = angles(obs)
        return (POS if d2 > 0 else NEG) if abs(t1) > high else (POS if d1 + c * d2 > 0 else NEG)

    return switching


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    policy, eps = _policy(style, rng), rng.uniform(0.02, 0.06)
    env = gym.make("Acrobot-v1")
    obs, _ = env.reset(seed=seed)

    def act(obs, states) -> int:
        return int(rng.integers(3)) if rng.random() < eps else policy(obs)

    return record(env, obs, act)


GAME = Game(
    name="acrobot",
    package="gymnasium (classic control)",
    kinds=("continuous low-dimensional states", "fixed task", "lengths set by skill"),
    styles=STYLES,
    counts=(90, 80, 70, 60),
    ci_counts=(18, 16, 14, 12),
    n_actions=3,
    play=play,
    gymnasium_env="Acrobot-v1",
    held_out=True,
    blind=True,
)
