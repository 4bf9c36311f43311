"""CartPole (Gymnasium classic control): four controllers that all balance the pole.

Continuous 4-d states (cart position, cart velocity, pole angle, pole angular velocity), two
actions (push left, push right), episodes up to 500 steps. Per-episode noise: each controller's
gains are drawn around its own centre, and it takes a random action with a small probability.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from benchmarks.zoo.common import Episode, Game, record

STYLES = (
    "angle PD (balance only)",
    "angle PD + centring the cart",
    "bang-bang on angular velocity",
    "lazy: corrects only past a threshold",
)


def _policy(style: int, rng: np.random.Generator):
    g = rng.normal(1.0, 0.1)
    if style == 0:
        return lambda s: int(g * (s[2] + 0.3 * s[3]) > 0)
    if style == 1:
        return lambda s: int(g * (s[2] + 0.3 * s[3]) + 0.05 * (s[0] + s[1]) > 0)
    if style == 2:
        return lambda s: int(s[3] + 0.1 * g * s[2] > 0)
    last = [0]

    def lazy(s):
        if abs(s[2] + 0.5 * s[3]) > 0.03 * g:
            last[0] = int(s[2] + 0.5 * s[3] > 0)
        return last[0]

    return lazy


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    env = gym.make("CartPole-v1")
    obs, _ = env.reset(seed=seed)
    policy, eps = _policy(style, rng), 0.05
    return record(env, obs, lambda o, _: int(rng.integers(2)) if rng.random() < eps else policy(o))


GAME = Game(
    name="cartpole",
    package="gymnasium (classic control)",
    kinds=("continuous low-dimensional states", "fixed task"),
    styles=STYLES,
    counts=(120, 120, 120, 120),
    ci_counts=(30, 30, 30, 30),
    n_actions=2,
    play=play,
    gymnasium_env="CartPole-v1",
)
