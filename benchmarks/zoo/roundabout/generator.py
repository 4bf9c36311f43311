"""Roundabout (highway-env's ``roundabout-v0``): four drivers entering a two-lane roundabout.

The ego car comes up the south road, enters the roundabout, and leaves by the north exit; every
episode the traffic differs (the positions, speeds, destinations and driver behaviours of the
four other cars come from the seed), so the moment to enter and whom to yield to differ too.
The state is the environment's own Kinematics observation: the ego car and the four others,
5 features each (presence, x, y, vx, vy; absolute coordinates, normalised by 100 m and 15 m/s),
flattened to 25 numbers. The actions are the discrete meta-actions: 0 lane left (towards the
inner ring), 1 idle, 2 lane right, 3 faster, 4 slower (target speeds 0, 8, 16 m/s). Per episode
each driver's time gaps and distances are drawn around its own centre, and it takes a random
speed action (idle, faster, slower) with a small probability.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import gymnasium as gym
import highway_env  # noqa: F401  (registers the highway-env environments)
import numpy as np

from benchmarks.zoo.common import Episode, Game, record

STYLES = (
    "eager: enters at speed, brakes only for an imminent car",
    "yielding: stops at the entry until the ring is clear",
    "slow and steady: 8 m/s throughout, never faster",
    "inner-ring: enters briskly, drives in the inner lane",
)
LEFT, IDLE, RIGHT, FASTER, SLOWER = range(5)
CONFIG = {"duration": 12}  # the default observation, actions and traffic; 12 s before the road ends
POS, VEL = 100.0, 15.0  # the observation's normalisation of positions and speeds
ENTRY = np.array([9.0, 20.0])  # where the south road meets the ring [m]
ENTRY_ANGLE = np.degrees(np.arctan2(ENTRY[1], ENTRY[0]))


class Scene:
    """The ego car's position and speed and the other cars, read from one observation."""

    def __init__(self, obs: np.ndarray) -> None:
        rows = obs[obs[:, 0] > 0.5]
        self.pos, self.vel = rows[0, 1:3] * POS, rows[0, 3:5] * VEL
        self.speed = float(np.hypot(*self.vel))
        self.others, self.others_vel = rows[1:, 1:3] * POS, rows[1:, 3:5] * VEL
        self.approaching = self.pos[1] > ENTRY[1] + 2.0
        self.to_entry = float(np.hypot(*(self.pos - ENTRY)))
        self.radius = float(np.hypot(*self.pos))

    def arrivals(self) -> np.ndarray:
        """Seconds before each car on the ring upstream of the entry reaches it (0 if there)."""
        times = []
        for p, v in zip(self.others, self.others_vel, strict=True):
            r = np.hypot(*p)
            angle = (np.degrees(np.arctan2(p[1], p[0])) - ENTRY_ANGLE + 180.0) % 360.0 - 180.0
            if 14.0 < r < 30.0 and -15.0 < angle < 150.0:
                times.append(max(angle, 0.0) * np.pi / 180.0 * r / max(np.hypot(*v), 2.0))
        return np.array(times)

    def ring_arrival(self) -> float:
        """Seconds before the first car on the ring reaches the entry (inf if none is coming)."""
        times = self.arrivals()
        return float(times.min()) if len(times) else np.inf

    def conflict(self, window: float, planned: float) -> bool:
        """Whether a car on the ring reaches the entry within ``window`` s of the ego car, at its
        speed now or at the ``planned`` one."""
        times = self.arrivals()
        if not self.approaching or not len(times):
            return False
        mine = self.to_entry / np.maximum([self.speed, planned], 4.0)
        return bool((np.abs(times[:, None] - mine[None, :]) < window).any())

    def danger(self, horizon: float, radius: float) -> bool:
        """Whether, both keeping their velocity, another car comes within ``radius`` m of the ego
        car in the next ``horizon`` seconds."""
        for h in np.linspace(0.0, horizon, 5):
            ego = self.pos + h * self.vel
            if (np.hypot(*(self.others + h * self.others_vel - ego).T) < radius).any():
                return True
        return False

    def gap_ahead(self) -> float:
        """Distance to the nearest car ahead of the ego car, within 3 m of its path."""
        if self.speed < 0.5 or not len(self.others):
            return np.inf
        heading = self.vel / self.speed
        rel = self.others - self.pos
        along, across = rel @ heading, np.abs(rel @ np.array([-heading[1], heading[0]]))
        ahead = (along > 0) & (across < 3.0)
        return float(along[ahead].min()) if ahead.any() else np.inf


def _speed(scene: Scene, target: float, gap: float) -> int:
    """Keep ``gap`` metres behind the car ahead, otherwise approach ``target`` m/s."""
    if scene.gap_ahead() < gap:
        return SLOWER
    if scene.speed < target - 3.0:
        return FASTER
    if scene.speed > target + 3.0:
        return SLOWER
    return IDLE


def _policy(style: int, rng: np.random.Generator) -> Callable[[np.ndarray], int]:
    gap, horizon, radius = rng.normal(12.0, 2.0), rng.normal(1.5, 0.2), rng.normal(7.0, 0.8)
    if style == 0:
        window = rng.normal(0.8, 0.15)

        def eager(obs: np.ndarray) -> int:
            s = Scene(obs)
            if s.danger(horizon, radius) or s.conflict(window, 16.0):
                return SLOWER if s.speed > 6.0 else IDLE
            return _speed(s, 16.0, gap)

        return eager
    if style == 1:
        clear, near = rng.normal(4.0, 0.5), rng.normal(22.0, 3.0)

        def yielding(obs: np.ndarray) -> int:
            s = Scene(obs)
            if s.danger(horizon + 0.5, radius) or s.conflict(1.5, 8.0):
                return SLOWER
            if s.approaching:
                if s.to_entry < near and s.ring_arrival() < clear:
                    return SLOWER
                return _speed(s, 8.0, gap)
            return _speed(s, 16.0, gap)

        return yielding
    if style == 2:
        wait, near = rng.normal(2.5, 0.4), rng.normal(14.0, 2.0)

        def steady(obs: np.ndarray) -> int:
            s = Scene(obs)
            if s.danger(horizon, radius) or s.conflict(1.5, 8.0):
                return SLOWER
            if s.approaching and s.to_entry < near and s.ring_arrival() < wait:
                return SLOWER
            return _speed(s, 8.0, 0.8 * gap)

        return steady
    window, exit_angle = rng.normal(1.2, 0.2), rng.normal(-40.0, 8.0)

    def inner(obs: np.ndarray) -> int:
        s = Scene(obs)
        if s.danger(horizon, radius) or s.conflict(window, 16.0):
            return SLOWER if s.speed > 6.0 else IDLE
        angle = np.degrees(np.arctan2(s.pos[1], s.pos[0]))
        if not s.approaching and 22.0 < s.radius < 27.0 and angle > exit_angle:
            return LEFT
        return _speed(s, 16.0, gap)

    return inner


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    with warnings.catch_warnings():  # gymnasium notes that roundabout-v0 is not the latest
        warnings.simplefilter("ignore", DeprecationWarning)
        env = gym.make("roundabout-v0", config=CONFIG)
    obs, _ = env.reset(seed=seed)
    policy, eps = _policy(style, rng), rng.uniform(0.02, 0.06)

    def act(obs, states) -> int:
        return int(rng.choice((IDLE, FASTER, SLOWER))) if rng.random() < eps else policy(obs)

    return record(env, obs, act, observe=np.ravel)


GAME = Game(
    name="roundabout",
    package="highway-env",
    kinds=("many features", "different task every episode"),
    styles=STYLES,
    counts=(70, 55, 45, 60),
    ci_counts=(18, 14, 11, 15),
    n_actions=5,
    play=play,
    gymnasium_env="roundabout-v0",
    gymnasium_kwargs={"config": CONFIG},
    held_out=True,
)
