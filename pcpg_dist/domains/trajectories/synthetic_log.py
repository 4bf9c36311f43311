"""Large synthetic step tables with known styles, written in chunks (bounded memory): the
scale benchmarks' and the streamed pipeline's tests' logs.

Each trajectory has a style ``s`` (uniform over ``styles``) and a noise level ``eps ~ U(0,
0.5)``. Its states drift along the style's direction as the episode goes (plus unit Gaussian
noise); its action is the style's linear policy (``argmax W_s x``) or, with probability eps, a
uniform random action; the reward is 1 when it took the style's action. Lengths are uniform in
15..35 actions (25 on average), and every trajectory ends on a closing row (action -1). So the
styles are clear in the states and actions, Step B's return ranks the trajectories by their
noise, and a BC agent can learn each style's policy (at most ``1 - 0.75 E[eps]`` ~ 0.81 of its
actions are predictable).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

CHUNK = 20_000  # trajectories generated and written at a time


def _chunk(
    rng: np.random.Generator, first: int, n: int, d: int, styles: int, n_actions: int
) -> pa.Table:
    fixed = np.random.default_rng(12345)  # the styles themselves: the same in every log
    drift = fixed.normal(size=(styles, d)).astype(np.float32)
    policy = fixed.normal(size=(styles, n_actions, d)).astype(np.float32)
    style = rng.integers(0, styles, n)
    length = rng.integers(15, 36, n) + 1  # actions + the closing row
    eps = rng.uniform(0.0, 0.5, n)
    rows = int(length.sum())
    start = np.cumsum(length) - length
    t = np.arange(rows) - np.repeat(start, length)
    s_row = np.repeat(style, length)
    frac = (t / np.repeat(length, length)).astype(np.float32)
    x = drift[s_row] * frac[:, None] + rng.normal(size=(rows, d)).astype(np.float32)
    greedy = np.einsum("rad,rd->ra", policy[s_row], x).argmax(1)
    random = rng.random(rows) < np.repeat(eps, length)
    action = np.where(random, rng.integers(0, n_actions, rows), greedy)
    reward = (action == greedy).astype(np.float64)
    last = start + length - 1
    action[last], reward[last] = -1, 0.0
    cols = {
        "trajectory": np.repeat(np.arange(first, first + n, dtype=np.int64), length),
        "t": t.astype(np.int64),
        "action": action.astype(np.int64),
        "reward": reward,
        "style": s_row.astype(np.int64),
    }
    cols.update({f"s{j}": x[:, j] for j in range(d)})
    return pa.table(cols)


def write_styled_log(
    path: str | Path,
    trajectories: int,
    d: int = 32,
    styles: int = 4,
    n_actions: int = 4,
    seed: int = 0,
    files: int = 1,
) -> int:
    """Write ``trajectories`` to ``path`` (a file, or with ``files > 1`` a folder of that many
    files); returns the number of rows."""
    rng = np.random.default_rng(seed)
    path = Path(path)
    per_file = -(-trajectories // files)
    if files > 1:
        path.mkdir(parents=True, exist_ok=True)
    rows = 0
    for f in range(files):
        lo, hi = f * per_file, min(trajectories, (f + 1) * per_file)
        target = path / f"part-{f:05d}.parquet" if files > 1 else path
        writer = None
        for first in range(lo, hi, CHUNK):
            table = _chunk(rng, first, min(CHUNK, hi - first), d, styles, n_actions)
            rows += table.num_rows
            if writer is None:
                writer = pq.ParquetWriter(target, table.schema)
            writer.write_table(table, row_group_size=250_000)
        if writer is not None:
            writer.close()
    return rows


def styled_dataset(path: str | Path, env: str = "log"):
    """A (small) log :func:`write_styled_log` wrote as one pcpg ``Dataset``, each trajectory's
    closing row its last state: what exporting it to Minari (``write_minari``) takes."""
    from pcpg_dist.dataset import Dataset

    table = pq.read_table(path).to_pandas()
    n_actions = int(table.action.max()) + 1
    states = [c for c in table.columns if c.startswith("s") and c[1:].isdigit()]
    trajs, styles = [], []
    for _, rows in table.groupby("trajectory", sort=True):
        trajs.append(
            {
                "states": rows[states].to_numpy(np.float32),
                "actions": rows.action.to_numpy()[:-1],  # the closing row has none
                "valid": np.ones((len(rows), n_actions), bool),
                "rewards": rows.reward.to_numpy()[:-1],
            }
        )
        styles.append(int(rows["style"].iloc[0]))
    return Dataset.from_trajectories(
        "trajectories", env, n_actions, trajs, styles=styles, success=[True] * len(trajs)
    )
