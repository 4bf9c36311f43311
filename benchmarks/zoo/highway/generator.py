"""Highway (highway-env's ``highway-fast-v0``): four drivers on a three-lane motorway in traffic.

Every episode is a different task: the traffic (positions, speeds, driver behaviours of the 12
other cars) is drawn from the seed. The state is highway-env's Kinematics observation of the ego
car and its four nearest neighbours (ahead or behind), 5 features each (presence, x, y, vx, vy;
the ego row absolute, the others relative to the ego; normalised), flattened to 25 numbers. The
actions are the discrete meta-actions: 0 lane left, 1 idle, 2 lane right, 3 faster, 4 slower.
Each driver reads the neighbours' relative positions from that observation; per episode its
headway, preferred speed and margins are drawn around its own centre, and it takes a random
speed action (idle, faster, slower) with a small probability.
"""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import highway_env  # noqa: F401  (registers the highway-env environments)
import numpy as np

from benchmarks.zoo.common import Episode, Game, record

STYLES = (
    "speeder: accelerates, overtakes on the left",
    "cautious: long headway, slows behind cars",
    "right-lane keeper: returns to the right",
    "weaver: moves to whichever lane is freer",
)
LEFT, IDLE, RIGHT, FASTER, SLOWER = range(5)
LANES, LANE_WIDTH = 3, 4.0
CONFIG = {
    "observation": {"type": "Kinematics", "vehicles_count": 5, "see_behind": True, "clip": False},
    "action": {"type": "DiscreteMetaAction", "target_speeds": [18, 22, 26, 30]},
    "lanes_count": LANES,
    "vehicles_count": 12,
    "duration": 20,
}
# The Kinematics observation's default normalisation ranges: x, y, vx in metres and m/s.
X_RANGE, Y_RANGE, V_RANGE = 200.0, LANE_WIDTH * LANES, 80.0
FREE = 200.0  # the gap to report where no neighbour is seen


class Scene:
    """The ego lane and speed and the gaps to the neighbours, read from one observation."""

    def __init__(self, obs: np.ndarray) -> None:
        self.lane = int(round(obs[0, 2] * Y_RANGE / LANE_WIDTH))
        self.speed = float(obs[0, 3] * V_RANGE)
        near = obs[1:][obs[1:, 0] > 0.5]
        self.dx = near[:, 1] * X_RANGE
        self.offset = np.round(near[:, 2] * Y_RANGE / LANE_WIDTH).astype(int)
        self.dv = near[:, 3] * V_RANGE

    def exists(self, off: int) -> bool:
        return 0 <= self.lane + off < LANES

    def ahead(self, off: int = 0) -> tuple[float, float]:
        """(gap, relative speed) to the nearest car ahead in the lane at ``off``."""
        mine = (self.offset == off) & (self.dx > 0)
        if not mine.any():
            return FREE, 0.0
        i = np.flatnonzero(mine)[np.argmin(self.dx[mine])]
        return float(self.dx[i] - 5.0), float(self.dv[i])

    def behind(self, off: int) -> tuple[float, float]:
        """(gap, closing speed) to the nearest car behind in the lane at ``off``."""
        mine = (self.offset == off) & (self.dx <= 0)
        if not mine.any():
            return FREE, 0.0
        i = np.flatnonzero(mine)[np.argmax(self.dx[mine])]
        return float(-self.dx[i] - 5.0), float(self.dv[i])

    def safe(self, off: int, front: float, back: float) -> bool:
        """Whether the lane at ``off`` exists and has room ``front`` ahead and ``back`` behind."""
        if not self.exists(off):
            return False
        gap_back, closing = self.behind(off)
        return self.ahead(off)[0] > front and gap_back > back + 2.0 * max(closing, 0.0)


def _follow(scene: Scene, headway: float, speed: float) -> int:
    """Keep ``headway`` seconds behind the car ahead and otherwise drive near ``speed``."""
    gap, dv = scene.ahead()
    if gap < headway * scene.speed + 2.0 * max(-dv, 0.0):
        return SLOWER
    if scene.speed < speed - 2.0 and gap > 1.5 * headway * scene.speed:
        return FASTER
    if scene.speed > speed + 2.0:
        return SLOWER
    return IDLE


def _policy(style: int, rng: np.random.Generator) -> Callable[[np.ndarray], int]:
    if style == 0:
        headway, look = rng.normal(0.8, 0.1), rng.normal(3.0, 0.4)
        room = rng.normal(25.0, 4.0)

        def speeder(obs: np.ndarray) -> int:
            s = Scene(obs)
            gap, dv = s.ahead()
            if gap < look * s.speed and dv < -1.0:
                if s.safe(-1, room, 10.0):
                    return LEFT
                if s.safe(1, room + 10.0, 12.0):
                    return RIGHT
            return _follow(s, headway, 40.0)

        return speeder
    if style == 1:
        headway, speed = rng.normal(2.4, 0.3), rng.normal(20.0, 1.5)
        patience = int(rng.integers(4, 9))
        stuck = [0]

        def cautious(obs: np.ndarray) -> int:
            s = Scene(obs)
            stuck[0] = stuck[0] + 1 if s.ahead()[0] < 1.3 * headway * s.speed else 0
            if stuck[0] > patience:
                for off in (1, -1):
                    if s.safe(off, 60.0, 30.0):
                        stuck[0] = 0
                        return RIGHT if off == 1 else LEFT
            return _follow(s, headway, speed)

        return cautious
    if style == 2:
        headway, speed = rng.normal(1.5, 0.2), rng.normal(25.0, 1.5)
        room, overtake = rng.normal(35.0, 5.0), rng.uniform(0.3, 0.8)

        def keeper(obs: np.ndarray) -> int:
            s = Scene(obs)
            if s.safe(1, room, 15.0):
                return RIGHT
            gap, dv = s.ahead()
            slow_ahead = gap < 1.2 * headway * s.speed and dv < -1.0
            if slow_ahead and s.safe(-1, room, 15.0) and rng.random() < overtake:
                return LEFT
            return _follow(s, headway, speed)

        return keeper
    headway, speed, margin = rng.normal(1.2, 0.15), rng.normal(27.0, 1.5), rng.normal(15.0, 5.0)

    def weaver(obs: np.ndarray) -> int:
        s = Scene(obs)
        here = s.ahead()[0]
        best = max((-1, 1), key=lambda off: s.ahead(off)[0] if s.exists(off) else -1.0)
        if s.ahead(best)[0] > here + margin and s.safe(best, 20.0, 10.0):
            return LEFT if best == -1 else RIGHT
        return _follow(s, headway, speed)

    return weaver


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    env = gym.make("highway-fast-v0", config=CONFIG)
    obs, _ = env.reset(seed=seed)
    policy, eps = _policy(style, rng), rng.uniform(0.02, 0.06)

    def act(obs, states) -> int:
        return int(rng.choice((IDLE, FASTER, SLOWER))) if rng.random() < eps else policy(obs)

    return record(env, obs, act, observe=np.ravel)


GAME = Game(
    name="highway",
    package="highway-env",
    kinds=("many features", "different task every episode"),
    styles=STYLES,
    counts=(70, 50, 60, 45),
    ci_counts=(18, 12, 15, 12),
    n_actions=5,
    play=play,
    gymnasium_env="highway-fast-v0",
    gymnasium_kwargs={"config": CONFIG},
)
