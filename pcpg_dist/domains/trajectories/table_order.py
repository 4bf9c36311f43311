"""A step table's rows grouped into trajectories and ordered by ``t``, each step with its own t.

The rows of a trajectory may lie anywhere in the file, or go on into a later file of a folder;
grouping them once, here, gives every later check (:mod:`.table_actions`, :mod:`.table`) the same
order and the same trajectory bounds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from pcpg_dist.common.errors import DataError
from pcpg_dist.domains.trajectories.table_files import Where

#: a trajectory's id as the user wrote it, by one of its rows (for messages)
NameOf = Callable[[int], str]


@dataclass(frozen=True)
class Trajectories:
    """The rows grouped by (env, trajectory) and ordered by t: ``order`` maps sorted rows to file
    rows; trajectory ``i`` is sorted rows ``starts[i]:ends[i]``."""

    order: np.ndarray
    starts: np.ndarray
    ends: np.ndarray
    key_env: np.ndarray
    key_traj: np.ndarray
    new: np.ndarray


def group_rows(
    t: np.ndarray, traj_raw: np.ndarray, env_code: np.ndarray, rows: int
) -> Trajectories:
    """Group rows by (env, trajectory) and order them by t (rows of one t: file order)."""
    order = np.lexsort((np.arange(rows), t, traj_raw, env_code))
    key_env, key_traj = env_code[order], traj_raw[order]
    new = np.r_[True, (np.diff(key_traj) != 0) | (np.diff(key_env) != 0)]
    starts = np.flatnonzero(new)
    ends = np.r_[starts[1:], rows]
    return Trajectories(order, starts, ends, key_env, key_traj, new)


def check_steps(groups: Trajectories, t: np.ndarray, where: Where, traj_name: NameOf) -> None:
    """Each step of a trajectory has its own t. A trajectory may go on into a later file of a
    folder, its t going on too; a later file whose t starts below an earlier file's is a restart:
    another trajectory under the same id."""
    order, new, rows = groups.order, groups.new, len(groups.order)
    t_sorted = t[order]
    repeated = np.r_[False, np.diff(t_sorted) == 0] & ~new
    file_of = (
        np.repeat(np.arange(len(where.parts)), [n for _, n in where.parts])
        if where.parts
        else np.zeros(rows, np.int64)
    )[order]
    back = np.r_[False, np.diff(file_of) < 0] & ~new
    if not (repeated | back).any():
        return
    at = int(np.flatnonzero(repeated | back)[0])
    row, previous = int(order[at]), int(order[at - 1])  # two rows of one trajectory, in t order
    (file, i), (prev_file, j) = where.locate(row), where.locate(previous)
    if file != prev_file:  # daily files whose ids restart at 0: not a t problem
        g = np.searchsorted(groups.starts, at, side="right") - 1
        group = np.arange(groups.starts[g], groups.ends[g])  # the trajectory's rows, in t order
        first, later = sorted({int(file_of[at]), int(file_of[at - 1])})
        here = int(t_sorted[group[file_of[group] == later]].min())
        there = int(t_sorted[group[file_of[group] == first]].max())
        prev_file, file = where.parts[first][0], where.parts[later][0]
        raise DataError(
            f"{file}: trajectory {traj_name(row)} appears both in {prev_file} and in this "
            f"file (its t restarts at {here} here after {there} there); trajectory ids "
            f"must be unique across a folder's files: give each file's trajectories distinct "
            f"ids (e.g. prefixed by the file's name)"
        )
    raise DataError(
        f"{file}: column 't', rows {j} and {i}: trajectory {traj_name(row)} has two rows with "
        f"t = {t[row]}; each step of a trajectory needs its own t"
    )
