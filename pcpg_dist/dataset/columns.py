"""A Dataset's Arrow columns: the step table pcpg writes and reads, and the masks in it.

Reading checks everything a file could get wrong (metadata, column types, nulls, missing or
repeated steps) before any array is built, each with one line naming the source, so the
:class:`~pcpg_dist.dataset.model.Dataset` constructor only checks what any builder could get wrong.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa

from pcpg_dist.common.errors import DataError
from pcpg_dist.common.files import SAFE_NAME

if TYPE_CHECKING:
    from pcpg_dist.dataset.model import Dataset

SCHEMA_VERSION = 2  # 2: `valid` is a list of booleans (was an int64 bitmask, capped at 63 actions)
MAX_ACTIONS = 1_000_000
MAX_STYLES = (
    100_000  # style ids index count tables (np.bincount): a style of 10**12 would be terabytes
)


def dataset_table(ds: Dataset) -> pa.Table:
    """``ds`` as an Arrow table of one row per step, its identity in the ``pcpg`` schema metadata."""
    per_row = ds.row_trajectory
    cols: dict[str, pa.Array] = {
        "trajectory": pa.array(ds.trajectory_ids[per_row], pa.int64()),
        "t": pa.array(ds.row_step, pa.int64()),
        "env": pa.array([ds.env] * ds.n_rows, pa.string()),
        "style": pa.array(ds.styles[per_row], pa.int64()),
    }
    for j in range(ds.state_dim):
        cols[f"s{j}"] = pa.array(ds.states[:, j], pa.float32())
    cols["action"] = pa.array(ds.actions, pa.int64())
    cols["valid"] = pa.FixedSizeListArray.from_arrays(
        pa.array(ds.valid.reshape(-1), pa.bool_()), ds.n_actions
    )
    cols["reward"] = pa.array(ds.rewards, pa.float64())
    cols["success"] = pa.array(ds.success[per_row], pa.bool_())
    cols["epsilon"] = pa.array(ds.epsilon[per_row], pa.float64())
    if ds.skill is not None:
        cols["skill"] = pa.array(ds.skill[per_row], pa.float64())
    if ds.source_ids is not None:
        cols["source_id"] = pa.array(ds.source_ids[per_row], pa.string())
    meta = {
        "pcpg": json.dumps(
            {
                "schema_version": SCHEMA_VERSION,
                "domain": ds.domain,
                "env": ds.env,
                "n_actions": ds.n_actions,
                "feature_names": list(ds.feature_names),
                "action_names": list(ds.action_names),
            }
        )
    }
    return pa.table(cols).replace_schema_metadata(meta)


def dataset_fields(table: pa.Table, source: str = "<table>") -> dict[str, Any]:
    """The keyword arguments of a Dataset read from a pcpg step table, every column checked."""
    domain, env, n_actions, feature_names, action_names = _read_metadata(table, source)
    check_action_memory(table.num_rows, n_actions, source, "n_actions in its metadata")
    names = table.column_names
    d = sum(1 for c in names if c.startswith("s") and c[1:].isascii() and c[1:].isdigit())
    _check_columns(table, source, n_actions, d)
    order, traj, starts, offsets = _trajectory_order(table, source)

    def col(name: str, dtype: type) -> np.ndarray:
        return table.column(name).to_numpy(zero_copy_only=False).astype(dtype)[order]

    valid = bool_lists(table.column("valid"), n_actions, source)[order]
    states = (
        np.stack([col(f"s{j}", np.float32) for j in range(d)], axis=1)
        if d
        else np.zeros((len(traj), 0), np.float32)
    )
    return dict(
        domain=domain,
        env=env,
        n_actions=n_actions,
        states=states,
        actions=col("action", np.int64),
        valid=valid,
        rewards=col("reward", np.float64),
        offsets=offsets,
        trajectory_ids=traj[starts],
        styles=col("style", np.int64)[starts],
        success=col("success", bool)[starts],
        epsilon=col("epsilon", np.float64)[starts],
        skill=col("skill", np.float64)[starts] if "skill" in names else None,
        source_ids=col("source_id", object)[starts] if "source_id" in names else None,
        feature_names=feature_names,
        action_names=action_names,
    )


def _read_metadata(
    table: pa.Table, source: str
) -> tuple[str, str, int, tuple[str, ...], tuple[str, ...]]:
    """Domain, env, number of actions, feature and action names from the ``pcpg`` metadata."""
    meta_raw = (table.schema.metadata or {}).get(b"pcpg")
    if meta_raw is None:
        raise DataError(
            f"{source}: not a pcpg dataset (no 'pcpg' schema metadata); a step table of your own "
            f"logs becomes pcpg datasets with `pcpg generate CONFIG --out DIR` (domain: "
            f"trajectories, docs/bring-your-own-data.md)"
        )
    try:
        meta = json.loads(meta_raw)
        domain, env, n_actions = meta["domain"], meta["env"], int(meta["n_actions"])
        feature_names = tuple(str(x) for x in meta.get("feature_names") or ())
        action_names = tuple(str(x) for x in meta.get("action_names") or ())
    except (ValueError, KeyError, TypeError, OverflowError, RecursionError) as e:
        raise DataError(f"{source}: unreadable 'pcpg' schema metadata ({str(e)[:200]})") from None
    for key, value in (("domain", domain), ("env", env)):  # both become file and folder names
        if (
            not isinstance(value, str)
            or not SAFE_NAME.match(value)
            or ".." in value
            or len(value) > 200
        ):
            raise DataError(
                f"{source}: 'pcpg' metadata {key} {str(value)[:80]!r} is not a plain name "
                f"(letters, digits, '_', '.', '+', '-'; no '/', no '..')"
            )
    if meta.get("schema_version") != SCHEMA_VERSION:
        raise DataError(
            f"{source}: dataset schema {meta.get('schema_version')} (this pcpg reads "
            f"{SCHEMA_VERSION}); regenerate it with this version"
        )
    if not 1 <= n_actions <= MAX_ACTIONS:
        raise DataError(f"{source}: n_actions {n_actions} outside 1..{MAX_ACTIONS}")
    return domain, env, n_actions, feature_names, action_names


def _check_columns(table: pa.Table, source: str, n_actions: int, d: int) -> None:
    """Every column pcpg writes is there with its type, and those that must have no nulls do not."""
    names = table.column_names
    expected = {
        "trajectory": pa.int64(),
        "t": pa.int64(),
        "env": pa.string(),
        "style": pa.int64(),
        **{f"s{j}": pa.float32() for j in range(d)},
        "action": pa.int64(),
        "valid": pa.list_(pa.bool_(), n_actions),
        "reward": pa.float64(),
        "success": pa.bool_(),
        "epsilon": pa.float64(),
    }
    for col, typ in expected.items():
        if col not in names:
            raise DataError(f"{source}: missing column '{col}' (expected {typ})")
        if table.schema.field(col).type != typ:
            raise DataError(
                f"{source}: column '{col}' has type {table.schema.field(col).type}, expected {typ}"
            )
    if "source_id" in names and table.schema.field("source_id").type != pa.string():
        raise DataError(
            f"{source}: column 'source_id' has type {table.schema.field('source_id').type}, "
            f"expected string"
        )
    for col in ("trajectory", "t", "style", "action", "valid", "success", "source_id"):
        if col in names and table.column(col).null_count:
            raise DataError(f"{source}: column '{col}' has null values")


def _trajectory_order(
    table: pa.Table, source: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows in (trajectory, t) order: the order, the sorted trajectory ids, each trajectory's first
    row and the offsets; every trajectory's t must run 0, 1, 2, ... without gaps or repeats."""
    traj = table.column("trajectory").to_numpy()
    t = table.column("t").to_numpy()
    order = np.lexsort((t, traj))
    traj, t = traj[order], t[order]
    starts = np.r_[0, np.nonzero(np.diff(traj))[0] + 1] if len(traj) else np.zeros(0, np.int64)
    offsets = np.r_[starts, len(traj)].astype(np.int64)
    lengths = np.diff(offsets)
    expect_t = np.arange(len(t)) - np.repeat(starts, lengths)
    if (t != expect_t).any():
        bad = int(traj[np.nonzero(t != expect_t)[0][0]])
        raise DataError(f"{source}: trajectory {bad} has missing or repeated time steps")
    return order, traj, starts, offsets


def mask_rows(valid: np.ndarray, rows: int, n_actions: int) -> np.ndarray:
    """(rows, n_actions) bool from a bool matrix, or from one integer bitmask per row (<= 63 actions)."""
    v = np.asarray(valid)
    if v.ndim == 1 and np.issubdtype(v.dtype, np.integer):
        if n_actions > 63:
            raise DataError(
                f"integer valid bitmasks hold at most 63 actions, not {n_actions}: pass a "
                f"(rows, n_actions) bool mask"
            )
        v = (v[:, None].astype(np.int64) >> np.arange(n_actions)) & 1
    if v.shape != (rows, n_actions):
        raise DataError(
            f"valid must have shape ({rows}, {n_actions}) (one mask per state), got {v.shape}"
        )
    return v.astype(bool)


#: bytes per (step, action) cell: the validity mask (1) and float32 BC logits with their gradient (8)
ACTION_CELL_BYTES = 9


def check_action_memory(rows: int, n_actions: int, source: str, origin: str) -> None:
    """Refuse, before the ``(rows, n_actions)`` validity mask is built, a number of actions whose
    mask and BC outputs would not fit in half this machine's memory (a 26 KB table with one action
    999999 asked for 8 GB and more, and the process was killed without a word)."""
    from pcpg_dist.common.memory import check_memory

    try:
        check_memory(
            float(rows) * n_actions * ACTION_CELL_BYTES,
            f"{rows} steps x {n_actions} actions ({origin})",
            "the number of actions: actions are numbered 0..n-1, so log them as "
            "0, 1, 2, ... for the moves your game has",
        )
    except ValueError as e:
        raise DataError(f"{source}: {e}") from None


def bool_lists(column: pa.ChunkedArray | pa.Array, n_actions: int, source: str) -> np.ndarray:
    """A Parquet column of per-row boolean lists as a (rows, n_actions) bool matrix.

    Every list must have exactly ``n_actions`` entries and no nulls; the error names the row.
    """
    arr = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    rows = len(arr)
    if arr.null_count:
        row = int(np.nonzero(arr.is_null().to_numpy(zero_copy_only=False))[0][0])
        raise DataError(f"{source}: column 'valid' is null in row {row}")
    if pa.types.is_fixed_size_list(arr.type):
        sizes = np.full(rows, arr.type.list_size)
    elif pa.types.is_list(arr.type) or pa.types.is_large_list(arr.type):
        sizes = np.diff(arr.offsets.to_numpy())
    else:
        raise DataError(
            f"{source}: column 'valid' has type {arr.type}; expected a list of booleans per row"
        )
    if not pa.types.is_boolean(arr.type.value_type):
        raise DataError(f"{source}: column 'valid' holds {arr.type.value_type}; expected booleans")
    if rows and (sizes != n_actions).any():
        row = int(np.nonzero(sizes != n_actions)[0][0])
        raise DataError(
            f"{source}: column 'valid', row {row}: {int(sizes[row])} entries, expected "
            f"{n_actions} (one per action)"
        )
    values = arr.flatten()
    if (
        values.null_count
    ):  # every list has n_actions entries (checked above): entry i is in row i // n_actions
        row = int(np.flatnonzero(values.is_null().to_numpy(zero_copy_only=False))[0]) // n_actions
        raise DataError(
            f"{source}: column 'valid', row {row}: a null entry in the list; every entry must be "
            f"true or false"
        )
    return values.to_numpy(zero_copy_only=False).astype(bool).reshape(rows, n_actions)
