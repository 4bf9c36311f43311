"""Reacher-v5 (Gymnasium MuJoCo): four ways of bringing a two-joint arm's tip to a target.

The target moves every episode (a different task each time). Continuous 10-d states (the env's
observation: cosines and sines of both joint angles, the target's position, both joint
velocities, the tip-minus-target vector), the 2-d torque discretised into a 3 x 3 grid (action
``3 * i + j``: shoulder torque ``LEVELS[i]``, elbow torque ``LEVELS[j]``), 50 steps an episode.
Every style solves the arm's inverse kinematics for the target once (the elbow branch nearer the
start) and drives each joint by the sign of a PD term with a deadband; they differ in the order
and damping of that drive. Per episode the gains and thresholds are drawn around the style's
centre, and a random action is taken with a small probability.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from benchmarks.zoo.common import Episode, Game, record

LEVELS = np.array([-0.3, 0.0, 0.3])
LINKS = (0.1, 0.11)
STYLES = (
    "both joints together",
    "shoulder first, then elbow",
    "elbow first, then shoulder",
    "overshoot: aims past the target, then comes back",
)


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def _goal(obs: np.ndarray) -> np.ndarray:
    """Joint angles that put the tip on the target: the IK branch nearer the current angles."""
    l1, l2 = LINKS
    target = obs[4:6]
    d = min(float(np.linalg.norm(target)), l1 + l2 - 1e-3)
    c = np.clip((d * d - l1 * l1 - l2 * l2) / (2 * l1 * l2), -1.0, 1.0)
    now = np.arctan2(obs[2:4], obs[0:2])
    best = None
    for sign in (1.0, -1.0):
        q2 = sign * np.arccos(c)
        q1 = np.arctan2(target[1], target[0]) - np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
        cand = np.array([q1, q2])
        if best is None or np.abs(_wrap(cand - now)).sum() < np.abs(_wrap(best - now)).sum():
            best = cand
    return best


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    kp, kd = rng.normal(1.0, 0.15), rng.normal(0.1, 0.02)
    dead = rng.normal(0.1, 0.02)
    first = rng.normal(0.3, 0.08)  # how close the first joint must get before the second moves
    eps = 0.05
    env = gym.make("Reacher-v5")
    obs, _ = env.reset(seed=seed)
    goal = _goal(obs)
    aim = goal
    if style == 3:  # first aim past the target, by a share of the way there
        aim = goal + rng.uniform(0.2, 0.4) * _wrap(goal - np.arctan2(obs[2:4], obs[0:2]))
    state = {"aim": aim}

    def act(obs, states) -> int:
        aim = state["aim"]
        err, vel = _wrap(aim - np.arctan2(obs[2:4], obs[0:2])), obs[6:8]
        if style == 3 and np.abs(err).max() < 0.5 * first:
            state["aim"] = goal  # passed the target: come back to it
        u = kp * err - kd * vel
        if style == 1 and abs(err[0]) > first:
            u[1] = -kd * vel[1]
        if style == 2 and abs(err[1]) > first:
            u[0] = -kd * vel[0]
        lv = np.where(np.abs(u) < dead, 1, np.where(u > 0, 2, 0))
        return int(rng.integers(9)) if rng.random() < eps else int(3 * lv[0] + lv[1])

    return record(env, obs, act, lambda a: np.array([LEVELS[a // 3], LEVELS[a % 3]], np.float32))


GAME = Game(
    name="mujoco_reacher",
    package="gymnasium (MuJoCo, mujoco)",
    kinds=("continuous control", "a different task every episode"),
    styles=STYLES,
    counts=(150, 120, 120, 90),
    ci_counts=(40, 30, 30, 24),
    n_actions=9,
    play=play,
    held_out=True,
)
