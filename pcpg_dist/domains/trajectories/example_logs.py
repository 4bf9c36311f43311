"""Example play logs in the step-table format: FrozenLake 8x8 (non-slippery) with scripted styles.

Not GridWorld and not used to choose any default: a held-out game for the ``trajectories``
domain's tests, benchmarks and docs. Each style walks to its own waypoint(s) before the goal by
breadth-first search over the frozen tiles; every trajectory gets its own noise level epsilon ~
U[0, noise_max] (a random move with probability epsilon, so skill varies and ranking means
something). States are the one-hot position (what ``gymnasium.spaces.flatten`` gives for
FrozenLake's ``Discrete(64)`` observation), actions are FrozenLake's (0 left, 1 down, 2 right,
3 up), reward 1 on reaching the goal, so the logs replay in ``gymnasium.make("FrozenLake-v1",
map_name="8x8", is_slippery=False)``.

``python -m pcpg_dist.domains.trajectories.example_logs OUT.parquet [--per-style N] [--seed S]``
"""

from __future__ import annotations

import argparse
from collections import deque
from pathlib import Path

import numpy as np

MAP_8X8 = (
    "SFFFFFFF",
    "FFFFFFFF",
    "FFFHFFFF",
    "FFFFFHFF",
    "FFFHFFFF",
    "FHHFFFHF",
    "FHFFHFHF",
    "FFFHFFFG",
)
MOVES = ((0, -1), (1, 0), (0, 1), (-1, 0))  # FrozenLake: left, down, right, up as (drow, dcol)
ACTION_NAMES = ("left", "down", "right", "up")
#: waypoints of each style before the goal (row, col)
STYLES = {
    "top-right": [(0, 7)],
    "bottom-left": [(7, 0)],
    "centre": [(4, 4)],
    "grand-tour": [(0, 7), (7, 0)],
}


def _step(pos: tuple[int, int], a: int, size: int) -> tuple[int, int]:
    r, c = pos[0] + MOVES[a][0], pos[1] + MOVES[a][1]
    return (r, c) if 0 <= r < size and 0 <= c < size else pos


def _first_moves(grid: tuple[str, ...], target: tuple[int, int]) -> dict[tuple[int, int], int]:
    """For every safe tile, the first move of a shortest safe path to ``target`` (BFS backwards)."""
    size = len(grid)
    best: dict[tuple[int, int], int] = {target: -1}
    queue = deque([target])
    while queue:
        cur = queue.popleft()
        for a in range(4):
            prev = (cur[0] - MOVES[a][0], cur[1] - MOVES[a][1])
            if (
                0 <= prev[0] < size
                and 0 <= prev[1] < size
                and prev not in best
                and grid[prev[0]][prev[1]] != "H"
            ):
                best[prev] = a
                queue.append(prev)
    return best


def play(
    style: list[tuple[int, int]],
    epsilon: float,
    rng: np.random.Generator,
    grid: tuple[str, ...] = MAP_8X8,
    max_steps: int = 100,
) -> tuple[list[int], list[int], float]:
    """One episode: visited tile indices, actions, return."""
    size = len(grid)
    goal = next((r, c) for r in range(size) for c in range(size) if grid[r][c] == "G")
    plans = [_first_moves(grid, w) for w in [*style, goal]]
    pos, stage, tiles, actions = (0, 0), 0, [0], []
    while len(actions) < max_steps:
        while stage < len(plans) - 1 and pos == [*style, goal][stage]:
            stage += 1
        a = int(rng.integers(4)) if rng.random() < epsilon else plans[stage][pos]
        pos = _step(pos, a, size)
        actions.append(a)
        tiles.append(pos[0] * size + pos[1])
        if grid[pos[0]][pos[1]] in "HG":
            break
    return tiles, actions, float(grid[pos[0]][pos[1]] == "G")


def frozenlake_logs(per_style: int = 200, seed: int = 0, noise_max: float = 0.3, envs: int = 1):
    """A pandas step table: trajectory, t, env, style, s0..s63, action (-1 on final rows), reward."""
    import pandas as pd

    rng = np.random.default_rng(seed)
    size = len(MAP_8X8)
    parts, tid = [], 0
    for e in range(envs):
        for s, waypoints in enumerate(STYLES.values()):
            for _ in range(per_style):
                tiles, actions, ret = play(waypoints, rng.uniform(0, noise_max), rng)
                n = len(tiles)
                onehot = np.zeros((n, size * size), np.float32)
                onehot[np.arange(n), tiles] = 1.0
                reward = np.zeros(n)
                reward[n - 2] = ret
                frame = pd.DataFrame(onehot, columns=[f"s{j}" for j in range(size * size)])
                frame.insert(0, "trajectory", tid)
                frame.insert(1, "t", np.arange(n))
                frame.insert(2, "env", f"lake{e}")
                frame.insert(3, "style", s)
                frame["action"] = [*actions, -1]
                frame["reward"] = reward
                parts.append(frame)
                tid += 1
    return pd.concat(parts, ignore_index=True)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="Parquet file to write")
    parser.add_argument("--per-style", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    table = frozenlake_logs(args.per_style, args.seed)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    table.to_parquet(args.out, index=False)
    print(
        f"wrote {args.out}: {table.trajectory.nunique()} trajectories, {len(table)} steps, "
        f"{len(STYLES)} styles"
    )


if __name__ == "__main__":
    main()
