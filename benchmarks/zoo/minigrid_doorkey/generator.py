"""MiniGrid-DoorKey-6x6-v0 (package minigrid): four ways of solving the key-door-goal task that
differ in only a few decisions.

Each episode (from ``env.reset(seed=...)``) places a splitting wall with a locked door, a key and
the agent (random direction) left of the wall; the goal is the bottom-right cell. The agent must
pick up the key, open the door and reach the goal. State (150 numbers): the agent's 7x7x3 partial
view (object, colour, state codes), flattened, then its direction (0 right, 1 down, 2 left, 3 up)
and its x, y. Actions: 0 turn left, 1 turn right, 2 forward, 3 pick up, 4 drop (never used),
5 toggle (open/close). Every style plans each sub-goal on the full grid with breadth-first
distances; per-episode noise: its tie-breaks, U-turn side and an epsilon of random turns/steps.
"""

from __future__ import annotations

from collections import deque

import gymnasium as gym
import minigrid  # noqa: F401  (registers the MiniGrid envs)
import numpy as np

from benchmarks.zoo.common import Episode, Game

STYLES = (
    "horizontal moves first",
    "vertical moves first",
    "closes the door behind it",
    "takes the key from above or below",
)
VEC = ((1, 0), (0, 1), (-1, 0), (0, -1))  # minigrid's direction vectors
EPSILON = 0.05


def _find(grid, kind: str) -> tuple[int, int] | None:
    for x in range(grid.width):
        for y in range(grid.height):
            cell = grid.get(x, y)
            if cell is not None and cell.type == kind:
                return x, y
    return None


def _distances(grid, targets: list[tuple[int, int]]) -> dict:
    """Breadth-first steps from every reachable free cell to the nearest of ``targets``."""
    dist = {t: 0 for t in targets}
    queue = deque(targets)
    while queue:
        x, y = queue.popleft()
        for vx, vy in VEC:
            n = (x + vx, y + vy)
            cell = grid.get(*n)
            if n not in dist and (cell is None or cell.can_overlap()):
                dist[n] = dist[(x, y)] + 1
                queue.append(n)
    return dist


def _turn(direction: int, want: int, uturn_left: bool) -> int:
    diff = (want - direction) % 4
    if diff == 0:
        return 2
    if diff == 2:
        return 0 if uturn_left else 1
    return 1 if diff == 1 else 0


def _goto(grid, pos, direction, targets, horizontal_first: bool, uturn_left: bool) -> int:
    """One step towards the nearest target cell (ties: straight on, then the preferred axis)."""
    dist = _distances(grid, targets)
    options = [d for d in range(4) if (pos[0] + VEC[d][0], pos[1] + VEC[d][1]) in dist]

    def key(d: int):
        n = (pos[0] + VEC[d][0], pos[1] + VEC[d][1])
        return dist[n], d != direction, (d % 2 == 0) != horizontal_first

    return _turn(direction, min(options, key=key), uturn_left)


def _face(grid, pos, direction, obj, sides, horizontal_first, uturn_left, act: int) -> int:
    """Go next to ``obj`` (on one of ``sides``, directions from the object), face it and ``act``."""
    spots = [(obj[0] + VEC[s][0], obj[1] + VEC[s][1]) for s in sides]
    spots = [p for p in spots if grid.get(*p) is None or grid.get(*p).can_overlap()]
    if pos in spots:
        want = next(d for d in range(4) if (pos[0] + VEC[d][0], pos[1] + VEC[d][1]) == obj)
        return act if want == direction else _turn(direction, want, uturn_left)
    return _goto(grid, pos, direction, spots, horizontal_first, uturn_left)


def _policy(style: int, rng: np.random.Generator):
    horizontal_first = style != 1 if rng.random() < 0.85 else style == 1
    uturn_left = bool(rng.random() < 0.5)
    closes = style == 2 and rng.random() < 0.9
    key_sides = (1, 3) if style == 3 and rng.random() < 0.9 else (0, 1, 2, 3)
    closed = [False]

    def act(env) -> int:
        u = env.unwrapped
        grid, pos, direction = u.grid, tuple(int(v) for v in u.agent_pos), int(u.agent_dir)
        key, door, goal = _find(grid, "key"), _find(grid, "door"), _find(grid, "goal")
        args = (horizontal_first, uturn_left)
        if key is not None and u.carrying is None:
            sides = [s for s in key_sides if _reachable(grid, key, s)] or (0, 1, 2, 3)
            return _face(grid, pos, direction, key, sides, *args, act=3)
        is_open = grid.get(*door).is_open
        if pos[0] < door[0] and not is_open:
            return _face(grid, pos, direction, door, (2,), *args, act=5)
        if closes and not closed[0] and pos[0] > door[0]:
            if is_open:
                return _face(grid, pos, direction, door, (0,), *args, act=5)
            closed[0] = True
        return _goto(grid, pos, direction, [goal], *args)

    return act


def _reachable(grid, obj, side: int) -> bool:
    cell = grid.get(obj[0] + VEC[side][0], obj[1] + VEC[side][1])
    return cell is None or cell.can_overlap()


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    env = gym.make("MiniGrid-DoorKey-6x6-v0")
    obs, _ = env.reset(seed=seed)
    policy = _policy(style, rng)
    states, actions, rewards = [], [], []
    done = False
    while not done:
        x, y = env.unwrapped.agent_pos
        states.append(np.concatenate([obs["image"].reshape(-1), [obs["direction"], x, y]]))
        a = int(rng.integers(3)) if rng.random() < EPSILON else policy(env)
        obs, r, terminated, truncated, _ = env.step(a)
        actions.append(a)
        rewards.append(r)
        done = terminated or truncated
    x, y = env.unwrapped.agent_pos
    states.append(np.concatenate([obs["image"].reshape(-1), [obs["direction"], x, y]]))
    env.close()
    return Episode(np.array(states), np.array(actions), np.array(rewards))


GAME = Game(
    name="minigrid_doorkey",
    package="minigrid",
    kinds=("image observations, flattened", "a different task every episode", "held out"),
    styles=STYLES,
    counts=(100, 80, 80, 60),
    ci_counts=(25, 20, 20, 15),
    n_actions=6,
    play=play,
    gymnasium_env=None,  # the state adds the agent's x, y to the env's own observation
    held_out=True,
)
