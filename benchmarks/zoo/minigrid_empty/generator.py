"""MiniGrid-Empty-8x8-v0 (package minigrid): four route styles on one fixed task.

The task never changes: the agent starts in the top-left corner (1, 1) facing right and must reach
the goal in the bottom-right corner (6, 6) of a walled 8x8 room. State (150 numbers): the agent's
7x7x3 partial view (object, colour, state codes), flattened, then its direction (0 right, 1 down,
2 left, 3 up) and its x, y. Actions: 0 turn left, 1 turn right, 2 forward. Every style walks a
route of waypoints with a greedy planner; per-episode noise is the route drawn for the episode and
an epsilon of random actions.
"""

from __future__ import annotations

import gymnasium as gym
import minigrid  # noqa: F401  (registers the MiniGrid envs)
import numpy as np

from benchmarks.zoo.common import Episode, Game

STYLES = (
    "wall-follower (left wall then bottom)",
    "straight-then-turn (row first)",
    "diagonal staircase",
    "detour: out, back, then to the goal",
)
VEC = ((1, 0), (0, 1), (-1, 0), (0, -1))  # minigrid's direction vectors
GOAL = (6, 6)
EPSILON = 0.06


def _state(obs: dict, env) -> np.ndarray:
    x, y = env.unwrapped.agent_pos
    return np.concatenate([obs["image"].reshape(-1), [obs["direction"], x, y]])


def _action(pos, direction: int, target, horizontal_first: bool, uturn_left: bool) -> int:
    """Turn towards, or step to, the next cell on an L-shaped route to ``target``."""
    dx, dy = target[0] - pos[0], target[1] - pos[1]
    moves = [d for d, (vx, vy) in enumerate(VEC) if (vx and vx * dx > 0) or (vy and vy * dy > 0)]
    if direction in moves:  # keep going straight while it still gets closer
        want = direction
    else:
        want = min(moves, key=lambda d: (d % 2 == 0) != horizontal_first)
    diff = (want - direction) % 4
    if diff == 0:
        return 2
    if diff == 2:
        return 0 if uturn_left else 1
    return 1 if diff == 1 else 0


def _route(style: int, rng: np.random.Generator) -> list[tuple[int, int]]:
    if style == 0:  # along the walls: usually left then bottom, sometimes top then right
        return [(1, 6), GOAL] if rng.random() < 0.75 else [(6, 1), GOAL]
    if style == 1:  # along the first row to a column, then down, then the rest of the way
        c = int(rng.choice([4, 5, 6], p=[0.2, 0.3, 0.5]))
        return [(c, 1), (c, 6), GOAL]
    if style == 2:  # a staircase: short runs along x and y in turn
        route, (x, y) = [], (1, 1)
        while (x, y) != GOAL:
            if x < 6:
                x = min(6, x + int(rng.integers(1, 3)))
                route.append((x, y))
            if y < 6:
                y = min(6, y + int(rng.integers(1, 3)))
                route.append((x, y))
        return route
    # a detour: far along one axis first, then back towards the start on the other, then the goal
    far = (int(rng.integers(4, 7)), int(rng.integers(1, 3)))
    back = (int(rng.integers(1, far[0] - 1)), int(rng.integers(3, 6)))
    return [far, back, GOAL] if rng.random() < 0.5 else [far[::-1], back[::-1], GOAL]


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    env = gym.make("MiniGrid-Empty-8x8-v0")
    obs, _ = env.reset(seed=seed)
    route = _route(style, rng)
    horizontal_first = style == 1 or (style == 3 and rng.random() < 0.5)
    uturn_left = bool(rng.random() < 0.5)
    states, actions, rewards = [_state(obs, env)], [], []
    done = False
    while not done:
        pos, direction = tuple(int(v) for v in env.unwrapped.agent_pos), int(obs["direction"])
        while len(route) > 1 and pos == route[0]:
            route.pop(0)
        if rng.random() < EPSILON:
            a = int(rng.integers(3))
        else:
            a = _action(pos, direction, route[0], horizontal_first, uturn_left)
        obs, r, terminated, truncated, _ = env.step(a)
        states.append(_state(obs, env))
        actions.append(a)
        rewards.append(r)
        done = terminated or truncated
    env.close()
    return Episode(np.array(states), np.array(actions), np.array(rewards))


GAME = Game(
    name="minigrid_empty",
    package="minigrid",
    kinds=("image observations, flattened", "fixed task"),
    styles=STYLES,
    counts=(120, 80, 60, 40),
    ci_counts=(30, 20, 15, 10),
    n_actions=3,
    play=play,
    gymnasium_env=None,  # the state adds the agent's x, y to the env's own observation
)
