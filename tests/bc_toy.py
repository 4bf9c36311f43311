"""A 5x5 toy grid with two play-styles, for the Step B/C and evaluation tests.

Start (0,0), goal (4,4), trap (2,2). Bonus B1 at (4,0), B2 at (0,4); state (x, y, b1, b2).
Style 0 fetches B1 then the goal, style 1 fetches B2 then the goal; each trajectory takes a
random action with its own probability epsilon ~ U[0, 0.3]. Actions: 0 right, 1 up, 2 left, 3 down;
moves off the grid are invalid (masked).
"""

from __future__ import annotations

import numpy as np

from pcpg_dist.dataset import Dataset

SIZE, GOAL, TRAP, B1, B2 = 5, (4, 4), (2, 2), (4, 0), (0, 4)
MOVES = np.array([(1, 0), (0, 1), (-1, 0), (0, -1)])
OPTIMAL = 150.0


def valid_bits(x: int, y: int) -> int:
    ok = [x < SIZE - 1, y < SIZE - 1, x > 0, y > 0]
    return sum(1 << i for i, o in enumerate(ok) if o)


def expert(state: np.ndarray, style: int) -> int:
    x, y, b1, b2 = (int(v) for v in state)
    target = GOAL if (b1 if style == 0 else b2) else (B1 if style == 0 else B2)
    order = (0, 1) if style == 0 else (1, 0)  # style 0 goes along the bottom, style 1 up the left
    for axis in order:
        delta = target[axis] - (x, y)[axis]
        if delta:
            return (0 if axis == 0 else 1) if delta > 0 else (2 if axis == 0 else 3)
    return 0


def step(state: np.ndarray, a: int) -> tuple[np.ndarray, bool, bool]:
    x, y = state[0] + MOVES[a][0], state[1] + MOVES[a][1]
    b1 = state[2] or (x, y) == B1
    b2 = state[3] or (x, y) == B2
    new = np.array([x, y, b1, b2], np.float32)
    return new, (x, y) == GOAL, (x, y) == TRAP


def run_episode(choose, rng: np.random.Generator, max_steps: int = 30) -> dict:
    s = np.zeros(4, np.float32)
    states, actions, valid, rewards, success = [s], [], [valid_bits(0, 0)], [], False
    for _ in range(max_steps):
        a = int(choose(s, valid[-1], rng))
        if not (valid[-1] >> a) & 1:
            raise ValueError("invalid action chosen")
        s, goal, trap = step(s, a)
        states.append(s)
        actions.append(a)
        valid.append(valid_bits(int(s[0]), int(s[1])))
        rewards.append(0.0)
        if goal or trap:
            success = goal
            break
    return {
        "states": np.array(states),
        "actions": np.array(actions),
        "valid": np.array(valid),
        "rewards": np.array(rewards),
        "success": success,
    }


def make_dataset(n_per_style: int = 100, seed: int = 0, styles: int = 2) -> Dataset:
    rng = np.random.default_rng(seed)
    trajs, labels, success, eps = [], [], [], []
    for style in range(styles):
        for _ in range(n_per_style):
            e = rng.uniform(0, 0.3)

            def choose(s, bits, r, style=style, e=e):
                if r.random() < e:
                    return r.choice([i for i in range(4) if (bits >> i) & 1])
                return expert(s, style)

            tr = run_episode(choose, rng)
            trajs.append(tr)
            labels.append(style)
            success.append(tr.pop("success"))
            eps.append(e)
    return Dataset.from_trajectories(
        "toy", "grid5", 4, trajs, labels, success, eps, feature_names=("x", "y", "b1", "b2")
    )


def rollout(policy, n_episodes: int, rng: np.random.Generator, max_steps: int = 30) -> Dataset:
    def choose(s, bits, r):
        valid = ((bits >> np.arange(4)) & 1).astype(bool)[None]
        return int(policy(s[None], valid, r)[0])

    trajs = [run_episode(choose, rng, max_steps) for _ in range(n_episodes)]
    success = [t.pop("success") for t in trajs]
    return Dataset.from_trajectories("toy", "grid5", 4, trajs, [-1] * n_episodes, success)


def returns(dataset: Dataset, style: int) -> np.ndarray:
    last = dataset.states[dataset.offsets[1:] - 1]
    return 100.0 * dataset.success + 50.0 * last[:, 2 + style]


def optimal_return(style: int) -> float:
    return OPTIMAL
