"""A user's step table (Parquet) -> validated Datasets, one per ``env`` value.

The contract (docs/bring-your-own-data.md), one row per step:

- required: ``trajectory`` (integer, string or bytes id), ``t`` (integer, distinct within a
  trajectory: its rows are ordered by ``t``, in any order in the file), ``action`` (integer 0..n-1;
  -1 only on a trajectory's last row, the state after its last action) and the state as numeric
  columns ``s0 .. s{d-1}``; integer columns may be floats holding whole numbers;
- optional: ``reward`` (float, received for the row's action), ``valid`` (a list of n booleans),
  ``env`` (one evaluation unit per value), ``style`` (ground truth, evaluation only), ``success``
  (bool), and any numeric per-trajectory column (constant within a trajectory) to rank by.

A trajectory whose last row still has an action gets a closing row that repeats its last state
with action -1 (pcpg's datasets end every trajectory on a state). Every problem is one
:class:`~pcpg_dist.common.errors.DataError` naming the file, the column and the row (0-based, in file
order); nothing is written before the whole table has passed. Reading the files is
:mod:`.table_files`' business, reading one column :mod:`.table_columns`', grouping the rows into
trajectories :mod:`.table_order`'s and checking the actions :mod:`.table_actions`'; this module runs
them in order, closes the trajectories, checks their returns and cuts the units.
"""

from __future__ import annotations

import reprlib
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from pcpg_dist.common.errors import DataError
from pcpg_dist.dataset import MAX_STYLES, Dataset
from pcpg_dist.domains.trajectories.table_actions import (
    check_action_signs,
    check_actions_in_range,
    count_actions,
    valid_masks,
)
from pcpg_dist.domains.trajectories.table_columns import (
    check_column_types,
    codes,
    first_null,
    floats,
    integers,
    is_integral,
    per_trajectory,
    row_error,
    state_columns,
    state_matrix,
)
from pcpg_dist.domains.trajectories.table_files import StepTable, Where, safe_env_name
from pcpg_dist.domains.trajectories.table_order import NameOf, Trajectories, check_steps, group_rows

DOMAIN = "trajectories"
REQUIRED = ("trajectory", "t", "action")
RESERVED = {"trajectory", "t", "action", "reward", "valid", "env", "style", "success"}
MAX_ENVS = 10_000  # each env is an evaluation unit with its own clustering and models


@dataclass(frozen=True)
class Closed:
    """The output rows, every trajectory ending on a state: ``src`` maps output rows to file rows."""

    states: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    valid: np.ndarray
    offsets: np.ndarray
    src: np.ndarray


def datasets_from_table(
    step: StepTable, n_actions: int | None = None, skill_column: str | None = None
) -> dict[str, Dataset]:
    """Validate a step table and cut it into one Dataset per ``env`` value (see the module doc)."""
    table, source = step.table, step.source
    where = Where(source, step.parts)
    s_cols = _check_columns(table, source, skill_column)
    rows = table.num_rows
    traj_col = table.column("trajectory")
    traj_raw, id_names = _trajectory_codes(traj_col, where)

    def traj_name(row: int) -> str:
        return reprlib.repr(
            int(traj_raw[row]) if is_integral(traj_col.type) else traj_col[row].as_py()
        )

    env_code, env_names = _env_codes(step, where)
    t = integers(table.column("t"), "t", where)
    actions = integers(table.column("action"), "action", where)
    groups = group_rows(t, traj_raw, env_code, rows)
    check_steps(groups, t, where, traj_name)
    a_sorted = actions[groups.order]
    check_action_signs(groups, actions, a_sorted, where, source)
    if "valid" in table.column_names:
        valid, n = valid_masks(table.column("valid"), n_actions, where, source, traj_name)
    else:
        valid, n = None, count_actions(actions, n_actions, where, source)
    check_actions_in_range(groups, actions, a_sorted, valid, n, n_actions, where)
    states = state_matrix(table, s_cols, where)
    rewards = floats(table, "reward", where) if "reward" in table.column_names else np.zeros(rows)
    styles, success, skill = _trajectory_columns(table, groups, skill_column, where)
    closed = _close(groups, a_sorted, states, actions, rewards, valid, n)
    _check_returns(closed, rewards, where, traj_name)
    return _cut(closed, groups, env_names, n, s_cols, styles, success, skill, id_names)


def _check_columns(table: pa.Table, source: str, skill_column: str | None) -> list[str]:
    """The state columns, after the required columns, the skill column, the rows and every
    column's type are checked."""
    names = table.column_names
    for col in REQUIRED:
        if col not in names:
            raise DataError(
                f"{source}: missing column '{col}' (required: trajectory, t, action, s0..s{{d-1}})"
            )
    s_cols = state_columns(names, source)
    if skill_column is not None and skill_column not in names:
        extra = sorted(set(names) - RESERVED - set(s_cols))
        raise DataError(
            f"{source}: trajectories.score names column '{skill_column}', which the table does "
            f"not have (its other columns: {', '.join(extra) or 'none'})"
        )
    if table.num_rows == 0:
        raise DataError(f"{source}: the table has no rows")
    check_column_types(table.schema, s_cols, skill_column, source)
    return s_cols


def _trajectory_codes(
    traj_col: pa.ChunkedArray, where: Where
) -> tuple[np.ndarray, np.ndarray | None]:
    """Trajectory ids (int or string) as int64 codes, and the user's ids by code where they are
    not integers (None otherwise)."""
    if traj_col.null_count:
        raise row_error(where, "trajectory", first_null(traj_col), "is empty (null)")
    if is_integral(traj_col.type):
        return integers(traj_col, "trajectory", where), None
    # strings, bytes (compared as bytes: they need not be UTF-8) or a dictionary of them
    code, ids = codes(traj_col)
    ids = np.asarray(ids, dtype=object)
    rank = np.argsort(np.argsort(ids))
    traj_raw = rank[code].astype(np.int64)  # ids numbered in sorted order
    id_names = np.array(
        [
            v.decode(errors="backslashreplace") if isinstance(v, bytes) else str(v)
            for v in ids[np.argsort(ids)]
        ],
        dtype=object,
    )
    return traj_raw, id_names


def _env_codes(step: StepTable, where: Where) -> tuple[np.ndarray, list[str]]:
    """Each row's unit (an index into the unit names), and the unit names."""
    table, source = step.table, step.source
    if "env" not in table.column_names:
        return np.zeros(table.num_rows, np.int64), [step.default_env]
    env_col = table.column("env")
    if env_col.null_count:
        raise row_error(where, "env", first_null(env_col), "is empty (null)")
    env_code, env_values = codes(env_col)
    if len(env_values) > MAX_ENVS:
        raise DataError(
            f"{source}: column 'env' has {len(env_values)} distinct values; each is an "
            f"evaluation unit, at most {MAX_ENVS} are allowed (is it a per-trajectory id?)"
        )
    for i, v in enumerate(env_values):
        if isinstance(v, bytes):
            try:
                env_values[i] = v.decode()
            except UnicodeDecodeError:
                raise row_error(
                    where,
                    "env",
                    int(np.argmax(env_code == i)),
                    f"{reprlib.repr(v)} is not UTF-8 text",
                ) from None
    env_names = [safe_env_name(v) for v in env_values]
    if len(set(env_names)) != len(env_names):
        clash = next(name for name in env_names if env_names.count(name) > 1)
        values = [v for v, name in zip(env_values, env_names, strict=True) if name == clash]
        raise DataError(
            f"{source}: column 'env': the values {reprlib.repr(values)} all become the unit name "
            f"{clash!r} (unit names name folders and files: they keep the ASCII letters, digits, "
            f"'_', '.', '+' and '-' of a value); rename them"
        )
    return env_code, env_names


def _trajectory_columns(
    table: pa.Table, groups: Trajectories, skill_column: str | None, where: Where
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Styles (-1 = unknown), success and the recorded skill, one value per trajectory."""
    names, starts, order = table.column_names, groups.starts, groups.order
    styles = (
        per_trajectory(
            integers(table.column("style"), "style", where), starts, order, "style", where
        )
        if "style" in names
        else np.full(len(starts), -1, np.int64)
    )
    if ((styles < -1) | (styles >= MAX_STYLES)).any():
        bad = int(np.flatnonzero((styles < -1) | (styles >= MAX_STYLES))[0])
        raise row_error(
            where,
            "style",
            int(order[starts[bad]]),
            f"style {styles[bad]}; styles are 0, 1, 2, ... (below {MAX_STYLES}), or -1 for unknown",
        )
    success = (
        per_trajectory(floats(table, "success", where) != 0, starts, order, "success", where)
        if "success" in names
        else np.ones(len(starts), bool)
    )
    skill = (
        per_trajectory(floats(table, skill_column, where), starts, order, skill_column, where)
        if skill_column is not None
        else None
    )
    return styles, success, skill


def _close(
    groups: Trajectories,
    a_sorted: np.ndarray,
    states: np.ndarray,
    actions: np.ndarray,
    rewards: np.ndarray,
    valid: np.ndarray | None,
    n: int,
) -> Closed:
    """The rows in trajectory order; a trajectory whose last row has an action ends on a repeat
    of its last state (action -1, reward 0)."""
    starts, ends, order = groups.starts, groups.ends, groups.order
    rows = len(order)
    open_end = a_sorted[ends - 1] >= 0
    lengths = (ends - starts) + open_end
    out_rows = int(lengths.sum())
    pos = np.r_[0, np.cumsum(lengths)[:-1]]
    dst = np.repeat(pos - starts, ends - starts) + np.arange(rows)  # sorted row -> output row
    closing = (pos + lengths - 1)[open_end]
    src_last = order[(ends - 1)[open_end]]

    src = np.empty(out_rows, np.int64)  # output row -> input row (closing rows repeat the last)
    src[dst] = order
    src[closing] = src_last
    identity = out_rows == rows and bool((src == np.arange(rows)).all())  # sorted, closed logs

    def place(values: np.ndarray) -> np.ndarray:
        return values if identity else values[src]

    all_states = place(states)
    all_actions = place(actions)
    all_actions[closing] = -1
    all_rewards = place(rewards)
    all_rewards[pos + lengths - 1] = 0.0  # nothing is received after the last action
    all_valid = (
        place(valid) if valid is not None else np.broadcast_to(np.ones(n, bool), (out_rows, n))
    )
    offsets = np.r_[0, np.cumsum(lengths)].astype(np.int64)
    return Closed(all_states, all_actions, all_rewards, all_valid, offsets, src)


def _check_returns(closed: Closed, rewards: np.ndarray, where: Where, traj_name: NameOf) -> None:
    """The returns Step B ranks by are finite (reported here, naming the largest reward)."""
    offsets, all_rewards = closed.offsets, closed.rewards
    with np.errstate(over="ignore", invalid="ignore"):
        returns = np.add.reduceat(all_rewards, offsets[:-1])
    if not np.isfinite(returns).all():
        i = int(np.flatnonzero(~np.isfinite(returns))[0])
        lo, hi = offsets[i], offsets[i + 1]
        row = int(closed.src[lo + np.argmax(np.abs(all_rewards[lo:hi]))])
        raise row_error(
            where,
            "reward",
            row,
            f"the rewards of trajectory {traj_name(row)} add up beyond a 64-bit "
            f"float (the largest, {rewards[row]:g}, is in this row); scale the "
            f"rewards down so that each trajectory's sum is finite",
        )


def _cut(
    closed: Closed,
    groups: Trajectories,
    env_names: list[str],
    n: int,
    s_cols: list[str],
    styles: np.ndarray,
    success: np.ndarray,
    skill: np.ndarray | None,
    id_names: np.ndarray | None,
) -> dict[str, Dataset]:
    """One Dataset per env value that has trajectories."""
    offsets = closed.offsets
    traj_env = groups.key_env[groups.starts]
    traj_ids = groups.key_traj[groups.starts]
    out: dict[str, Dataset] = {}
    for code, env in enumerate(env_names):
        sel = np.flatnonzero(traj_env == code)
        if not len(sel):
            continue
        lo, hi = offsets[sel[0]], offsets[sel[-1] + 1]
        out[env] = Dataset(
            domain=DOMAIN,
            env=env,
            n_actions=n,
            states=closed.states[lo:hi],
            actions=closed.actions[lo:hi],
            valid=np.ascontiguousarray(closed.valid[lo:hi]),
            rewards=closed.rewards[lo:hi],
            offsets=offsets[sel[0] : sel[-1] + 2] - lo,
            trajectory_ids=traj_ids[sel],
            styles=styles[sel],
            success=success[sel],
            epsilon=np.full(len(sel), np.nan),
            feature_names=tuple(s_cols),
            skill=None if skill is None else skill[sel],
            source_ids=None if id_names is None else id_names[traj_ids[sel]],
        )
    return out
