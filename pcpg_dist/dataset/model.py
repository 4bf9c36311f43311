"""The Dataset: the one interchange format every stage reads and every user can open.

In memory a :class:`Dataset` keeps the rows in trajectory order with CSR-style ``offsets``, so a
trajectory is a slice and subsets are cheap; its constructor checks what any builder could get
wrong (shapes, NaN states, actions outside the mask). The columns on disk are
:mod:`pcpg_dist.dataset.columns`', the files and manifests :mod:`pcpg_dist.dataset.files`'.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pyarrow as pa

from pcpg_dist.common.errors import DataError
from pcpg_dist.dataset.columns import MAX_STYLES, dataset_fields, dataset_table, mask_rows


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
    def row_step(self) -> np.ndarray:
        """Index (0, 1, ...) of each row within its trajectory: the step t."""
        return np.arange(self.n_rows) - self.offsets[self.row_trajectory]

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
        trajectory_arrays: Sequence[dict[str, np.ndarray]],
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
        for i, tr in enumerate(trajectory_arrays):
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
                valid.append(mask_rows(tr["valid"], len(s), n_actions))
            except DataError as e:
                raise DataError(f"{where}: {e}") from None
            states.append(s)
            actions.append(np.r_[a, -1])
            rewards.append(np.r_[r, 0.0])
            lengths.append(len(s))
        n = len(trajectory_arrays)
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
        """This dataset as pcpg's step table (one row per step, identity in the metadata)."""
        return dataset_table(self)

    @staticmethod
    def from_table(table: pa.Table, source: str = "<table>") -> Dataset:
        """A dataset from pcpg's step table; one DataError naming ``source`` otherwise."""
        fields = dataset_fields(table, source)
        try:
            return Dataset(**fields)
        except DataError as e:
            raise DataError(f"{source}: {e}") from None
