"""InvertedDoublePendulum-v5 (Gymnasium MuJoCo): four controllers that all keep the pendulum up.

Continuous 9-d states (the env's observation: cart position, sines and cosines of both hinge
angles, the three velocities, the constraint force), the cart's continuous force discretised into
seven levels (action i pushes with ``LEVELS[i]``), episodes up to 500 steps. Each controller is a
discrete-time LQR on the model's own linearisation about the upright (finite differences through
MuJoCo, computed once) with its own cost weights; per episode the weights are drawn around the
style's centre, and with a small probability the chosen level is nudged to a neighbouring one.
"""

from __future__ import annotations

from functools import cache

import gymnasium as gym
import numpy as np
import scipy.linalg

from benchmarks.zoo.common import Episode, Game, record

LEVELS = np.array([-0.6, -0.25, -0.08, 0.0, 0.08, 0.25, 0.6])
MAX_STEPS = 500
STYLES = (
    "stiff LQR: angles costly, torque cheap",
    "soft LQR: torque costly, small smooth pushes",
    "cart-centring LQR: holds the cart near the middle",
    "lazy LQR: no push inside a deadband",
)
# (Q diagonal over x, theta1, theta2, x', theta1', theta2'; R) per style.
WEIGHTS = (
    ((1.0, 10.0, 10.0, 1.0, 1.0, 1.0), 1.0),
    ((1.0, 10.0, 10.0, 1.0, 1.0, 1.0), 100.0),
    ((30.0, 10.0, 10.0, 10.0, 1.0, 1.0), 1.0),
    ((1.0, 10.0, 10.0, 1.0, 1.0, 1.0), 3.0),
)


@cache
def _linearisation() -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of one env step (frame_skip substeps) about the upright, by central differences."""
    env = gym.make("InvertedDoublePendulum-v5").unwrapped
    env.reset(seed=0)
    nq = env.model.nq

    def step(x: np.ndarray, a: float) -> np.ndarray:
        env.set_state(x[:nq].copy(), x[nq:].copy())
        env.do_simulation(np.array([a]), env.frame_skip)
        return np.concatenate([env.data.qpos, env.data.qvel])

    x0, h = np.zeros(2 * nq), 1e-5
    a = np.stack(
        [(step(x0 + h * e, 0.0) - step(x0 - h * e, 0.0)) / (2 * h) for e in np.eye(2 * nq)]
    )
    b = (step(x0, h) - step(x0, -h)) / (2 * h)
    env.close()
    return a.T, b[:, None]


def _gain(q: np.ndarray, r: float) -> np.ndarray:
    a, b = _linearisation()
    p = scipy.linalg.solve_discrete_are(a, b, np.diag(q), np.array([[r]]))
    return np.linalg.solve(np.array([[r]]) + b.T @ p @ b, b.T @ p @ a)[0]


def _lqr_state(obs: np.ndarray) -> np.ndarray:
    """(x, theta1, theta2, x', theta1', theta2') from the observation."""
    return np.array(
        [obs[0], np.arctan2(obs[1], obs[3]), np.arctan2(obs[2], obs[4]), obs[5], obs[6], obs[7]]
    )


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    q, r = WEIGHTS[style]
    gain = _gain(np.array(q) * rng.lognormal(0.0, 0.3, 6), r * rng.lognormal(0.0, 0.3))
    deadband = rng.uniform(0.08, 0.2) if style == 3 else 0.0
    eps = 0.05
    env = gym.make("InvertedDoublePendulum-v5", max_episode_steps=MAX_STEPS)
    obs, _ = env.reset(seed=seed)

    def act(obs, states) -> int:
        force = -float(gain @ _lqr_state(obs))
        a = 3 if abs(force) < deadband else int(np.argmin(np.abs(LEVELS - force)))
        if rng.random() < eps:
            a = int(np.clip(a + rng.choice((-1, 1)), 0, len(LEVELS) - 1))
        return a

    return record(env, obs, act, lambda a: np.array([LEVELS[a]], np.float32))


GAME = Game(
    name="mujoco_pendulum",
    package="gymnasium (MuJoCo, mujoco)",
    kinds=("continuous control", "continuous low-dimensional states", "fixed task"),
    styles=STYLES,
    counts=(60, 60, 60, 60),
    ci_counts=(15, 15, 15, 15),
    n_actions=len(LEVELS),
    play=play,
)
