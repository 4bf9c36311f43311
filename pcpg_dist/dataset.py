"""The Dataset: the one interchange format every stage reads and every user can open.

On disk: ``DIR/<domain>-<env>.parquet``, one row per step, plus ``DIR/manifest.json`` with the
config, seeds, versions, row counts and a SHA-256 per file. Columns:

- ``trajectory`` (int64), ``t`` (int64), ``env`` (string), ``style`` (int64, -1 = unknown)
- ``s0`` .. ``s{d-1}`` (float32 state features)
- ``action`` (int64; -1 on a trajectory's final state), ``valid`` (fixed-size list of ``n_actions``
  booleans: which actions are valid in that state; any number of actions)
- ``reward`` (float64: the reward received for the action taken in this row; 0 on the final row)
- ``success`` (bool) and ``epsilon`` (float64, NaN = unknown): per-trajectory, repeated per row
- ``skill`` (float64, optional): a per-trajectory skill score recorded with the data (a user's own
  column, ranked by Step B when the config says so), repeated per row

Plain pandas, polars or DuckDB read it. In memory a :class:`Dataset` keeps the rows in trajectory
order with CSR-style ``offsets``, so a trajectory is a slice and subsets are cheap.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pcpg_dist.common.errors import DataError, first_line
from pcpg_dist.common.files import (
    FILE_MODE,
    SAFE_NAME,
    atomic_write_bytes,
    confined,
    sha256_file,
    temp_beside,
)

SCHEMA_VERSION = 2  # 2: `valid` is a list of booleans (was an int64 bitmask, capped at 63 actions)
MANIFEST = "manifest.json"
MAX_ACTIONS = 1_000_000
MAX_STYLES = (
    100_000  # style ids index count tables (np.bincount): a style of 10**12 would be terabytes
)
MAX_MANIFEST_BYTES = 64 << 20  # a manifest lists files and a config: kilobytes


@dataclass(frozen=True, eq=False)
class Dataset:
    """Variable-length trajectories of one (domain, environment), stored row-wise.

    Rows of trajectory ``i`` are ``offsets[i]:offsets[i+1]``; every trajectory has at least one row
    and its last row has ``action == -1``.
    """

    domain: str
    env: str
    n_actions: int
    states: np.ndarray  # (rows, d) float32
    actions: np.ndarray  # (rows,) int64, -1 on final rows
    valid: np.ndarray  # (rows, n_actions) bool
    rewards: np.ndarray  # (rows,) float64
    offsets: np.ndarray  # (n + 1,) int64
    trajectory_ids: np.ndarray  # (n,) int64
    styles: np.ndarray  # (n,) int64, -1 = unknown
    success: np.ndarray  # (n,) bool
    epsilon: np.ndarray  # (n,) float64, NaN = unknown
    feature_names: tuple[str, ...] = field(default=())
    action_names: tuple[str, ...] = field(default=())
    skill: np.ndarray | None = None  # (n,) float64: a recorded per-trajectory skill score, if any
    #: (n,) str: the ids the user's logs gave the trajectories where they were not integers
    #: (``trajectory_ids`` numbers those in sorted order); written back by ``pcpg classify``
    source_ids: np.ndarray | None = None

    def __post_init__(self) -> None:
        rows, n = len(self.actions), len(self.trajectory_ids)
        where = f"dataset {self.domain}-{self.env}"
        if self.states.ndim != 2 or len(self.states) != rows:
            raise DataError(
                f"{where}: states must have shape (rows={rows}, d), got {self.states.shape}"
            )
        if len(self.rewards) != rows:
            raise DataError(f"{where}: rewards has {len(self.rewards)} rows, expected {rows}")
        if self.n_actions < 1:
            raise DataError(f"{where}: n_actions must be >= 1, got {self.n_actions}")
        if self.valid.dtype != bool or self.valid.shape != (rows, self.n_actions):
            raise DataError(
                f"{where}: valid must be a bool mask of shape (rows={rows}, n_actions="
                f"{self.n_actions}), got {self.valid.dtype} {self.valid.shape}"
            )
        for name in ("styles", "success", "epsilon", "skill", "source_ids"):
            if getattr(self, name) is not None and len(getattr(self, name)) != n:
                raise DataError(
                    f"{where}: {name} has {len(getattr(self, name))} entries, expected {n}"
                )
        if n and (self.styles.min() < -1 or self.styles.max() >= MAX_STYLES):
            bad = int(np.argmax((self.styles < -1) | (self.styles >= MAX_STYLES)))
            raise DataError(
                f"{where}: trajectory {int(self.trajectory_ids[bad])} has style {int(self.styles[bad])}; "
                f"styles are 0, 1, 2, ... (below {MAX_STYLES}) or -1 (unknown)"
            )
        if len(self.offsets) != n + 1 or self.offsets[0] != 0 or self.offsets[-1] != rows:
            raise DataError(f"{where}: offsets must run from 0 to {rows} with {n + 1} entries")
        lengths = np.diff(self.offsets)
        if n and lengths.min() < 1:
            bad = int(self.trajectory_ids[np.argmin(lengths)])
            raise DataError(
                f"{where}: trajectory {bad} has zero length; every trajectory needs a state"
            )
        if rows and not np.isfinite(self.states).all():
            row = int(np.nonzero(~np.isfinite(self.states).all(axis=1))[0][0])
            traj = int(self.trajectory_ids[np.searchsorted(self.offsets, row, side="right") - 1])
            raise DataError(
                f"{where}: trajectory {traj} has a NaN or infinite state feature (row {row})"
            )
        final = np.zeros(rows, bool)
        final[self.offsets[1:] - 1] = True
        if n and (self.actions[final] != -1).any():
            raise DataError(f"{where}: the final row of every trajectory must have action -1")
        bad = ~final & ((self.actions < 0) | (self.actions >= self.n_actions))
        if bad.any():
            row = int(np.argmax(bad))
            traj = int(self.trajectory_ids[np.searchsorted(self.offsets, row, side="right") - 1])
            raise DataError(
                f"{where}: trajectory {traj} (row {row}) takes action {int(self.actions[row])}, "
                f"outside 0..{self.n_actions - 1}"
            )
        if self.feature_names and len(self.feature_names) != self.state_dim:
            raise DataError(
                f"{where}: {len(self.feature_names)} feature names for {self.state_dim} features"
            )
        if self.action_names and len(self.action_names) != self.n_actions:
            raise DataError(
                f"{where}: {len(self.action_names)} action names for {self.n_actions} actions"
            )

    # ----------------------------------------------------------------- shape
    @property
    def n_trajectories(self) -> int:
        return len(self.trajectory_ids)

    @property
    def n_rows(self) -> int:
        return len(self.actions)

    @property
    def state_dim(self) -> int:
        return int(self.states.shape[1])

    @property
    def lengths(self) -> np.ndarray:
        """Number of states (rows) of each trajectory."""
        return np.diff(self.offsets)

    @property
    def returns(self) -> np.ndarray:
        """Undiscounted return (sum of rewards) of each trajectory."""
        if not self.n_rows:
            return np.zeros(0)
        with np.errstate(
            over="ignore", invalid="ignore"
        ):  # an overflow is inf, which Step B reports
            return np.add.reduceat(self.rewards, self.offsets[:-1])

    @property
    def row_trajectory(self) -> np.ndarray:
        """Index (0..n-1) of the trajectory each row belongs to."""
        return np.repeat(np.arange(self.n_trajectories), self.lengths)

    @property
    def valid_mask(self) -> np.ndarray:
        """(rows, n_actions) bool: which actions are valid in each row's state (= ``valid``)."""
        return self.valid

    @property
    def step_rows(self) -> np.ndarray:
        """Indices of rows where an action was taken (all but each trajectory's final row)."""
        return np.nonzero(self.actions >= 0)[0]

    def trajectory_states(self, i: int) -> np.ndarray:
        return self.states[self.offsets[i] : self.offsets[i + 1]]

    # ----------------------------------------------------------------- subsets
    def subset(self, indices: Sequence[int] | np.ndarray) -> Dataset:
        """The trajectories at positions ``indices`` (0..n-1), in that order."""
        idx = np.asarray(indices, dtype=np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= self.n_trajectories):
            raise DataError(f"subset index out of range 0..{self.n_trajectories - 1}")
        lengths = self.lengths[idx]
        starts = self.offsets[idx]
        rows = (
            np.repeat(starts - np.cumsum(np.r_[0, lengths[:-1]]), lengths)
            + np.arange(lengths.sum())
            if idx.size
            else np.zeros(0, np.int64)
        )
        return Dataset(
            domain=self.domain,
            env=self.env,
            n_actions=self.n_actions,
            states=self.states[rows],
            actions=self.actions[rows],
            valid=self.valid[rows],
            rewards=self.rewards[rows],
            offsets=np.r_[0, np.cumsum(lengths)].astype(np.int64),
            trajectory_ids=self.trajectory_ids[idx],
            styles=self.styles[idx],
            success=self.success[idx],
            epsilon=self.epsilon[idx],
            feature_names=self.feature_names,
            action_names=self.action_names,
            skill=None if self.skill is None else self.skill[idx],
            source_ids=None if self.source_ids is None else self.source_ids[idx],
        )

    def with_styles(self, styles: np.ndarray) -> Dataset:
        """The same trajectories with other style labels (e.g. cluster assignments)."""
        styles = np.asarray(styles, dtype=np.int64)
        if styles.shape != (self.n_trajectories,):
            raise DataError(f"styles must have shape ({self.n_trajectories},), got {styles.shape}")
        return replace(self, styles=styles)

    @staticmethod
    def concat(parts: Sequence[Dataset], renumber: bool = True) -> Dataset:
        """Join datasets of one domain and state width; trajectory ids are renumbered 0..n-1."""
        if not parts:
            raise DataError("cannot concatenate an empty list of datasets")
        first = parts[0]
        for p in parts[1:]:
            if p.state_dim != first.state_dim or p.n_actions != first.n_actions:
                raise DataError(
                    f"cannot join {p.domain}-{p.env} (d={p.state_dim}, actions={p.n_actions}) with "
                    f"{first.domain}-{first.env} (d={first.state_dim}, actions={first.n_actions})"
                )
        lengths = np.concatenate([p.lengths for p in parts])
        ids = np.concatenate([p.trajectory_ids for p in parts])
        envs = {p.env for p in parts}
        return Dataset(
            domain=first.domain,
            env=first.env if len(envs) == 1 else "+".join(sorted(envs)),
            n_actions=first.n_actions,
            states=np.concatenate([p.states for p in parts]),
            actions=np.concatenate([p.actions for p in parts]),
            valid=np.concatenate([p.valid for p in parts]),
            rewards=np.concatenate([p.rewards for p in parts]),
            offsets=np.r_[0, np.cumsum(lengths)].astype(np.int64),
            trajectory_ids=np.arange(len(ids), dtype=np.int64) if renumber else ids,
            styles=np.concatenate([p.styles for p in parts]),
            success=np.concatenate([p.success for p in parts]),
            epsilon=np.concatenate([p.epsilon for p in parts]),
            feature_names=first.feature_names,
            action_names=first.action_names,
            skill=(
                np.concatenate([p.skill for p in parts])
                if all(p.skill is not None for p in parts)
                else None
            ),
            source_ids=(
                np.concatenate([p.source_ids for p in parts])
                if all(p.source_ids is not None for p in parts)
                else None
            ),
        )

    @staticmethod
    def from_trajectories(
        domain: str,
        env: str,
        n_actions: int,
        trajectories: Sequence[dict[str, np.ndarray]],
        styles: Sequence[int],
        success: Sequence[bool],
        epsilon: Sequence[float] | None = None,
        feature_names: tuple[str, ...] = (),
        action_names: tuple[str, ...] = (),
    ) -> Dataset:
        """Build from per-trajectory dicts with ``states`` (T+1, d), ``actions`` (T,),
        ``valid`` (T+1, n_actions) bool (or, for up to 63 actions, (T+1,) integer bitmasks) and
        ``rewards`` (T,)."""
        states, actions, valid, rewards, lengths = [], [], [], [], []
        for i, tr in enumerate(trajectories):
            s = np.asarray(tr["states"], np.float32)
            a, r = np.asarray(tr["actions"], np.int64), np.asarray(tr["rewards"], np.float64)
            where = f"dataset {domain}-{env}, trajectory {i}"
            if s.ndim != 2 or a.ndim != 1 or len(s) != len(a) + 1:
                raise DataError(
                    f"{where}: states of shape {s.shape} and actions of shape {a.shape}; a "
                    f"trajectory of T actions has states of shape (T + 1, d), the last after "
                    f"the last action"
                )
            if r.shape != a.shape:
                raise DataError(
                    f"{where}: rewards of shape {r.shape}, expected {a.shape} (one per action)"
                )
            try:
                valid.append(_mask_rows(tr["valid"], len(s), n_actions))
            except DataError as e:
                raise DataError(f"{where}: {e}") from None
            states.append(s)
            actions.append(np.r_[a, -1])
            rewards.append(np.r_[r, 0.0])
            lengths.append(len(s))
        n = len(trajectories)
        d = states[0].shape[1] if states else 0
        return Dataset(
            domain=domain,
            env=env,
            n_actions=n_actions,
            states=np.concatenate(states) if states else np.zeros((0, d), np.float32),
            actions=np.concatenate(actions) if n else np.zeros(0, np.int64),
            valid=np.concatenate(valid) if n else np.zeros((0, n_actions), bool),
            rewards=np.concatenate(rewards) if n else np.zeros(0),
            offsets=np.r_[0, np.cumsum(lengths)].astype(np.int64),
            trajectory_ids=np.arange(n, dtype=np.int64),
            styles=np.asarray(styles, np.int64),
            success=np.asarray(success, bool),
            epsilon=np.full(n, np.nan) if epsilon is None else np.asarray(epsilon, np.float64),
            feature_names=feature_names,
            action_names=action_names,
        )

    # ----------------------------------------------------------------- Arrow
    def to_table(self) -> pa.Table:
        per_row = self.row_trajectory
        cols: dict[str, pa.Array] = {
            "trajectory": pa.array(self.trajectory_ids[per_row], pa.int64()),
            "t": pa.array(np.arange(self.n_rows) - self.offsets[per_row], pa.int64()),
            "env": pa.array([self.env] * self.n_rows, pa.string()),
            "style": pa.array(self.styles[per_row], pa.int64()),
        }
        for j in range(self.state_dim):
            cols[f"s{j}"] = pa.array(self.states[:, j], pa.float32())
        cols["action"] = pa.array(self.actions, pa.int64())
        cols["valid"] = pa.FixedSizeListArray.from_arrays(
            pa.array(self.valid.reshape(-1), pa.bool_()), self.n_actions
        )
        cols["reward"] = pa.array(self.rewards, pa.float64())
        cols["success"] = pa.array(self.success[per_row], pa.bool_())
        cols["epsilon"] = pa.array(self.epsilon[per_row], pa.float64())
        if self.skill is not None:
            cols["skill"] = pa.array(self.skill[per_row], pa.float64())
        if self.source_ids is not None:
            cols["source_id"] = pa.array(self.source_ids[per_row], pa.string())
        meta = {
            "pcpg": json.dumps(
                {
                    "schema_version": SCHEMA_VERSION,
                    "domain": self.domain,
                    "env": self.env,
                    "n_actions": self.n_actions,
                    "feature_names": list(self.feature_names),
                    "action_names": list(self.action_names),
                }
            )
        }
        return pa.table(cols).replace_schema_metadata(meta)

    @staticmethod
    def from_table(table: pa.Table, source: str = "<table>") -> Dataset:
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
            raise DataError(
                f"{source}: unreadable 'pcpg' schema metadata ({str(e)[:200]})"
            ) from None
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
        check_action_memory(table.num_rows, n_actions, source, "n_actions in its metadata")
        names = table.column_names
        d = sum(1 for c in names if c.startswith("s") and c[1:].isascii() and c[1:].isdigit())
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

        def col(name: str, dtype: type) -> np.ndarray:
            return table.column(name).to_numpy(zero_copy_only=False).astype(dtype)[order]

        valid = bool_lists(table.column("valid"), n_actions, source)[order]
        states = (
            np.stack([col(f"s{j}", np.float32) for j in range(d)], axis=1)
            if d
            else np.zeros((len(traj), 0), np.float32)
        )
        try:
            return Dataset(
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
        except DataError as e:
            raise DataError(f"{source}: {e}") from None


def _mask_rows(valid: np.ndarray, rows: int, n_actions: int) -> np.ndarray:
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


# --------------------------------------------------------------------- files
def file_name(domain: str, env: str) -> str:
    return f"{domain}-{env}.parquet"


def content_digest(ds: Dataset) -> str:
    """A hash of what a clusterer reads of ``ds`` (states, actions, valid masks, trajectory
    bounds), for cache keys: a domain may derive its clustering input from any setting (Mario's
    valid mask comes from the training episodes, so from the split)."""
    h = hashlib.sha256()
    for a in (ds.states, ds.actions, ds.valid, ds.offsets):
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.data)
    return h.hexdigest()[:20]


def write_parquet(dataset: Dataset, path: Path) -> str:
    """Write one dataset atomically; returns its SHA-256."""
    path = Path(path)
    fd, tmp = temp_beside(path)
    os.fchmod(fd, FILE_MODE)
    os.close(fd)
    try:
        pq.write_table(dataset.to_table(), tmp, compression="zstd")
        digest = sha256_file(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return digest


DECODE_COPIES = 4  # Arrow table, NumPy columns, sorted copies, the Dataset: peak while loading


#: what pcpg reads where it reads its own datasets (for the message on a file that is not Parquet)
DATASET_READS = (
    "this reads pcpg datasets, which `pcpg generate CONFIG --out DIR` writes from a Parquet step "
    "table of your own logs (domain: trajectories, docs/bring-your-own-data.md)"
)
#: how pandas reads a text table, by the file's suffix
TEXT_READERS = {
    ".csv": "pandas.read_csv(path)",
    ".tsv": "pandas.read_csv(path, sep='\\t')",
    ".json": "pandas.read_json(path)",
    ".jsonl": "pandas.read_json(path, lines=True)",
    ".ndjson": "pandas.read_json(path, lines=True)",
}


def unreadable_parquet(path: Path, error: Exception, reads: str = DATASET_READS) -> DataError:
    """One line for a file Arrow cannot read as Parquet: a CSV or JSON file (by its suffix) is told
    what ``reads`` and how to convert it; any other file gets Arrow's reason."""
    reader = TEXT_READERS.get(Path(path).suffix.lower())
    if reader is None:
        return DataError(f"{path}: not a readable Parquet file ({first_line(error)})")
    return DataError(
        f"{path}: not a Parquet file: {reads}; a {Path(path).suffix.lower()[1:].upper()} file "
        f"converts to Parquet with {reader}.to_parquet(...)"
    )


def check_parquet_memory(files: Sequence[Path], source: str, reads: str = DATASET_READS) -> None:
    """Refuse Parquet input whose decoded size, read from the file footers before any data, would
    not fit in half this machine's memory (a 'small' file can hold a huge, well-compressed table)."""
    from pcpg_dist.common.memory import gib, machine_memory

    need, rows = 0, 0
    for f in files:
        try:
            meta = pq.read_metadata(f)
        except (pa.ArrowException, OSError) as e:
            raise unreadable_parquet(f, e, reads) from None
        raw = sum(meta.row_group(i).total_byte_size for i in range(meta.num_row_groups))
        need += max(raw, meta.num_rows * max(meta.num_columns, 1) * 8) * DECODE_COPIES
        rows += meta.num_rows
    if need > machine_memory() // 2:
        raise DataError(
            f"{source}: {rows} rows need about {gib(need)} of memory to load, more than half of "
            f"this machine's {gib(machine_memory())}; split the data into smaller files or "
            f"environments, or use a machine with more memory"
        )


def read_parquet(path: Path, expected_sha256: str | None = None) -> Dataset:
    path = Path(path)
    if not path.is_file():
        raise DataError(
            f"{path}: dataset file " + ("is not a regular file" if path.exists() else "not found")
        )
    if expected_sha256 is not None and sha256_file(path) != expected_sha256:
        raise DataError(
            f"{path}: content hash does not match {MANIFEST} (file changed or corrupted)"
        )
    check_parquet_memory([path], str(path))
    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError) as e:
        raise unreadable_parquet(path, e) from None
    return Dataset.from_table(table, source=str(path))


def write_datasets(directory: Path, datasets: Sequence[Dataset], manifest: dict) -> Path:
    """Write every dataset and then ``manifest.json`` (config, seeds, versions, rows, hashes).

    The manifest is written last, so a directory whose manifest exists is complete.
    """
    directory = Path(directory)
    files = {}
    for ds in datasets:
        name = confined(directory, file_name(ds.domain, ds.env), "dataset file name").name
        files[name] = {
            "sha256": write_parquet(ds, directory / name),
            "rows": ds.n_rows,
            "trajectories": ds.n_trajectories,
            "domain": ds.domain,
            "env": ds.env,
        }
    full = {"schema_version": SCHEMA_VERSION, **manifest, "files": files}
    atomic_write_bytes(
        directory / MANIFEST, json.dumps(full, indent=2, sort_keys=True, default=str).encode()
    )
    return directory / MANIFEST


def read_manifest(directory: Path) -> dict:
    path = Path(directory) / MANIFEST
    if not path.is_file():
        raise DataError(f"{path}: manifest not found (is {directory} a pcpg dataset directory?)")
    if path.stat().st_size > MAX_MANIFEST_BYTES:
        raise DataError(
            f"{path}: {path.stat().st_size} bytes; a manifest holds at most {MAX_MANIFEST_BYTES}"
        )
    try:
        manifest = json.loads(path.read_bytes().decode("utf-8"))
        manifest["files"]  # noqa: B018 - presence check
    except (ValueError, KeyError, TypeError, IndexError, RecursionError) as e:
        raise DataError(
            f"{path}: unreadable manifest ({type(e).__name__}: {str(e)[:200]})"
        ) from None
    if not isinstance(manifest, dict) or not isinstance(manifest["files"], dict):
        raise DataError(
            f"{path}: 'files' must map file names to their hashes (a JSON object), got "
            f"{type(manifest['files']).__name__}"
        )
    return manifest


def load_datasets(directory: Path) -> dict[str, Dataset]:
    """All datasets of a directory, keyed by env, each checked against the manifest's hash."""
    directory = Path(directory)
    manifest = read_manifest(directory)
    out = {}
    for name, info in manifest["files"].items():
        if not isinstance(info, dict):
            raise DataError(f"{directory / MANIFEST}: entry {str(name)[:80]!r} must be a mapping")
        path = confined(directory, name, "manifest file")
        if path.is_symlink() and not path.resolve().is_relative_to(directory.resolve()):
            raise DataError(
                f"{path}: a link to {path.resolve()}, outside {directory}; refusing to read it"
            )
        ds = read_parquet(path, expected_sha256=info.get("sha256"))
        if ds.n_rows != info.get("rows"):
            raise DataError(
                f"{directory / name}: {ds.n_rows} rows, manifest says {str(info.get('rows'))[:40]}"
            )
        if ds.env in out:
            raise DataError(
                f"{directory / name}: environment {ds.env!r} appears in two files of the manifest"
            )
        out[ds.env] = ds
    return out


def load_dataset(path: Path) -> Dataset:
    """One dataset from a Parquet file; checked against the manifest beside it when there is one."""
    path = Path(path)
    manifest_path = path.parent / MANIFEST
    expected = None
    if manifest_path.is_file():
        info = read_manifest(path.parent)["files"].get(path.name)
        expected = info.get("sha256") if isinstance(info, dict) else None
    return read_parquet(path, expected_sha256=expected)
