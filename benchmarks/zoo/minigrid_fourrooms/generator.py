"""MiniGrid-FourRooms-v0 (package minigrid): four route preferences on a new task every episode.

Four 8x8 rooms joined by random doorways in a 19x19 grid; start, direction, doorways and goal
change every episode (all from ``env.reset(seed=...)``). State (152 numbers): the agent's 7x7x3
partial view (object, colour, state codes), flattened, then its direction (0 right, 1 down, 2 left,
3 up), its x, y and the goal's x, y (the task). Actions: 0 turn left, 1 turn right, 2 forward.
Every style plans on the full grid (``env.unwrapped.grid``) with Dijkstra under its own cell costs
and follows the plan greedily; per-episode noise: its cost weights, tie-breaks and an epsilon of
random actions. Episodes end at the goal or after the env's 100 steps.
"""

from __future__ import annotations

import heapq

import gymnasium as gym
import minigrid  # noqa: F401  (registers the MiniGrid envs)
import numpy as np

from benchmarks.zoo.common import Episode, Game

STYLES = (
    "shortest path in long straight runs (horizontal first)",
    "shortest path as a staircase (turns at every tie)",
    "hugs the walls",
    "keeps to the room centres",
)
VEC = ((1, 0), (0, 1), (-1, 0), (0, -1))  # minigrid's direction vectors
EPSILON = 0.05


def _distance_field(free: np.ndarray, goal, cost: np.ndarray) -> np.ndarray:
    """Cheapest cost from every cell to ``goal``, entering a cell costing ``cost`` there."""
    dist = np.full(free.shape, np.inf)
    dist[goal] = 0.0
    heap = [(0.0, goal)]
    while heap:
        d, (x, y) = heapq.heappop(heap)
        if d > dist[x, y]:
            continue
        for vx, vy in VEC:
            n = (x + vx, y + vy)
            if free[n] and d + cost[x, y] < dist[n]:
                dist[n] = d + cost[x, y]
                heapq.heappush(heap, (dist[n], n))
    return dist


def _cell_costs(style: int, free: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Each style's price of entering a cell: 1, plus what the style dislikes there."""
    wall_dist = np.full(free.shape, 9.0)  # Chebyshev distance to the nearest wall, up to 3
    for r in (3, 2, 1):
        near = np.zeros_like(free)
        for dx in range(-r, r + 1):
            for dy in range(-r, r + 1):
                near |= ~np.roll(np.roll(free, dx, 0), dy, 1)
        wall_dist[near] = r
    cost = np.ones(free.shape) + rng.uniform(0.0, 0.05, free.shape)  # random tie-breaks
    if style == 2:
        cost += rng.uniform(3.0, 5.0) * (wall_dist > 1)
    elif style == 3:
        cost += rng.uniform(2.0, 4.0) * np.clip(3 - wall_dist, 0, None)
    return cost


def _goal(grid) -> tuple[int, int]:
    return next(
        (x, y)
        for x in range(grid.width)
        for y in range(grid.height)
        if grid.get(x, y) is not None and grid.get(x, y).type == "goal"
    )


def _state(obs: dict, env, goal: tuple[int, int]) -> np.ndarray:
    x, y = env.unwrapped.agent_pos
    return np.concatenate([obs["image"].reshape(-1), [obs["direction"], x, y, *goal]])


def _action(
    pos, direction, dist, cost, prefer_horizontal: bool, staircase: int | None, uturn_left: bool
) -> int:
    """Turn towards, or step to, the cheapest neighbour (ties: straight on, or for a staircase a
    turn away from ``staircase``, the last move's direction, then the preferred axis)."""

    def key(d: int):
        n = (pos[0] + VEC[d][0], pos[1] + VEC[d][1])
        straight = (d != direction) if staircase is None else (d == staircase)
        return (round(dist[n] + cost[pos], 6), straight, (d % 2 == 0) != prefer_horizontal)

    want = min(range(4), key=key)
    diff = (want - direction) % 4
    if diff == 0:
        return 2
    if diff == 2:
        return 0 if uturn_left else 1
    return 1 if diff == 1 else 0


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    env = gym.make("MiniGrid-FourRooms-v0")
    obs, _ = env.reset(seed=seed)
    grid = env.unwrapped.grid
    free = np.array(
        [
            [grid.get(x, y) is None or grid.get(x, y).can_overlap() for y in range(grid.height)]
            for x in range(grid.width)
        ]
    )
    goal = _goal(grid)
    cost = _cell_costs(style, free, rng)
    if style < 2:  # the shortest-path styles: plain step counts, ties broken by the style
        cost = np.ones(free.shape)
    dist = _distance_field(free, goal, cost)
    prefer_horizontal = style == 0 if style < 2 else bool(rng.random() < 0.5)
    if style < 2 and rng.random() < 0.15:  # now and then the other axis first
        prefer_horizontal = not prefer_horizontal
    zigzag, last_move = style == 1 and rng.random() < 0.9, int(obs["direction"])
    uturn_left = bool(rng.random() < 0.5)
    states, actions, rewards = [_state(obs, env, goal)], [], []
    done = False
    while not done:
        pos = tuple(int(v) for v in env.unwrapped.agent_pos)
        if rng.random() < EPSILON:
            a = int(rng.integers(3))
        else:
            a = _action(
                pos,
                int(obs["direction"]),
                dist,
                cost,
                prefer_horizontal,
                last_move if zigzag else None,
                uturn_left,
            )
        if a == 2:
            last_move = int(obs["direction"])
        obs, r, terminated, truncated, _ = env.step(a)
        states.append(_state(obs, env, goal))
        actions.append(a)
        rewards.append(r)
        done = terminated or truncated
    env.close()
    return Episode(np.array(states), np.array(actions), np.array(rewards))


GAME = Game(
    name="minigrid_fourrooms",
    package="minigrid",
    kinds=("image observations, flattened", "a different task every episode"),
    styles=STYLES,
    counts=(100, 100, 80, 60),
    ci_counts=(25, 25, 20, 15),
    n_actions=3,
    play=play,
    gymnasium_env=None,  # the state adds the agent's and the goal's x, y to the env's observation
)
