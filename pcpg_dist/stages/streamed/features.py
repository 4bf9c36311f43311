"""Per-trajectory summary features of a streamed log, built from additive per-block partials.

A block holds any rows of any trajectories (a trajectory may span blocks and files), so each
block is reduced to one row of *sums* per trajectory it touches (:func:`step_partials`); the
engine sums the rows of one trajectory across blocks (a hash aggregation), and
:func:`trajectory_features` turns the sums into the features the clusterer sees: log length,
action frequencies, and the mean and spread of every state dimension. They are the
action-and-state statistics of the ceiling panel's summary model (docs/clustering.md), less the
quantiles, which do not add up across blocks.
"""

from __future__ import annotations

import numpy as np

from pcpg_dist.common.errors import DataError
from pcpg_dist.dataset import MAX_STYLES


def partial_columns(d: int, n_actions: int) -> list[str]:
    """The summed columns of :func:`step_partials` (all but ``trajectory`` and ``style``)."""
    return (
        ["rows", "acted", "ret"]
        + [f"sum{j}" for j in range(d)]
        + [f"sq{j}" for j in range(d)]
        + [f"a{k}" for k in range(n_actions)]
    )


def check_block(batch: dict[str, np.ndarray], states: tuple[str, ...], n_actions: int) -> None:
    """What a block must hold: integer trajectory ids, actions in -1..n-1, styles in -1..99999,
    finite states."""
    tid, action = batch["trajectory"], batch["action"]
    if not np.issubdtype(tid.dtype, np.integer):
        raise DataError(
            f"column 'trajectory' holds {tid.dtype}; a streamed log needs integer trajectory ids"
        )
    bad = np.flatnonzero((action < -1) | (action >= n_actions))
    if len(bad):
        raise DataError(
            f"column 'action': trajectory {int(tid[bad[0]])} has action {int(action[bad[0]])}; "
            f"actions are 0..{n_actions - 1} (-1 on a closing row)"
        )
    if "style" in batch:
        style = batch["style"]
        wrong = np.flatnonzero((style < -1) | (style >= MAX_STYLES))
        if len(wrong):
            raise DataError(
                f"column 'style': trajectory {int(tid[wrong[0]])} has style {style[wrong[0]]}; "
                f"styles are 0..{MAX_STYLES - 1} or -1 (unknown)"
            )
    for name in states:
        col = batch[name]
        if not np.isfinite(col).all():
            row = int(np.flatnonzero(~np.isfinite(col))[0])
            raise DataError(
                f"column {name!r}: trajectory {int(tid[row])} has a non-finite state value; "
                "states must be finite numbers"
            )


def step_partials(
    batch: dict[str, np.ndarray], states: tuple[str, ...], n_actions: int
) -> dict[str, np.ndarray]:
    """One row of sums per trajectory in the block: rows, acted steps, return, the sum and sum of
    squares of every state column, and a count per action."""
    check_block(batch, states, n_actions)
    order = np.argsort(batch["trajectory"], kind="stable")
    tid = batch["trajectory"][order]
    ids, start = np.unique(tid, return_index=True)
    action = batch["action"][order]
    reward = batch["reward"][order] if "reward" in batch else np.zeros(len(tid))
    out: dict[str, np.ndarray] = {
        "trajectory": ids.astype(np.int64),
        "rows": np.diff(np.r_[start, len(tid)]).astype(np.float64),
        "acted": np.add.reduceat((action >= 0).astype(np.float64), start),
        "ret": np.add.reduceat(np.where(action >= 0, reward, 0.0).astype(np.float64), start),
        "style": (
            np.maximum.reduceat(batch["style"][order].astype(np.int64), start)
            if "style" in batch
            else np.full(len(ids), -1, np.int64)
        ),
    }
    x = np.stack([batch[c] for c in states], 1)[order].astype(np.float32)
    sums = np.add.reduceat(x, start, dtype=np.float64)
    squares = np.add.reduceat(np.square(x, out=x), start, dtype=np.float64)
    for j in range(len(states)):
        out[f"sum{j}"], out[f"sq{j}"] = sums[:, j], squares[:, j]
    for k in range(n_actions):
        out[f"a{k}"] = np.add.reduceat((action == k).astype(np.float64), start)
    return out


def trajectory_features(summed: dict[str, np.ndarray], d: int, n_actions: int) -> dict:
    """Summed partials (one row per trajectory) -> ``x`` (features, float32), ``trajectory``,
    ``length`` (actions taken), ``ret``, ``style``."""
    rows = summed["rows"]
    acted = np.maximum(summed["acted"], 1.0)
    means = np.stack([summed[f"sum{j}"] for j in range(d)], 1) / rows[:, None]
    squares = np.stack([summed[f"sq{j}"] for j in range(d)], 1) / rows[:, None]
    spread = np.sqrt(np.maximum(squares - means * means, 0.0))
    freqs = np.stack([summed[f"a{k}"] for k in range(n_actions)], 1) / acted[:, None]
    x = np.concatenate([np.log(acted)[:, None], freqs, means, spread], 1).astype(np.float32)
    return {
        "trajectory": summed["trajectory"].astype(np.int64),
        "x": x,
        "length": summed["acted"].astype(np.int64),
        "ret": summed["ret"].astype(np.float64),
        "style": summed["style"].astype(np.int64),
    }
