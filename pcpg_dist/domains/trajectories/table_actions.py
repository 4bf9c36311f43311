"""A step table's actions: their number (from the valid lists, the config or the largest id),
their range, and the valid masks they must lie in.

Checked after the rows are grouped (:mod:`.table_order`): -1 is allowed only on a trajectory's last
row, so where a row lies in its trajectory decides whether its action is right.
"""

from __future__ import annotations

import logging
import reprlib

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pcpg_dist.common.errors import DataError
from pcpg_dist.dataset import MAX_ACTIONS, bool_lists, check_action_memory
from pcpg_dist.domains.trajectories.table_columns import action_origin, first_null, row_error
from pcpg_dist.domains.trajectories.table_files import Where
from pcpg_dist.domains.trajectories.table_order import NameOf, Trajectories


def check_action_signs(
    groups: Trajectories, actions: np.ndarray, a_sorted: np.ndarray, where: Where, source: str
) -> None:
    """Actions are 0..n-1, -1 allowed only on a trajectory's last row; some row has a step."""
    last = np.zeros(len(actions), bool)
    last[groups.ends - 1] = True
    neg = (a_sorted < 0) & ~(last & (a_sorted == -1))
    if neg.any():
        row = int(groups.order[np.flatnonzero(neg)[0]])
        raise row_error(
            where,
            "action",
            row,
            f"action {actions[row]} is not allowed (0..n-1; -1 only on a trajectory's last row)",
        )
    if (a_sorted == -1).all():  # only closing rows: no state is followed by an action
        raise DataError(
            f"{source}: no trajectory has a step: each of the {len(groups.starts)} trajectories "
            f"is a single row (action -1, its closing state); a trajectory needs rows with actions "
            f"0..n-1 before its last"
        )


def valid_masks(
    vcol: pa.ChunkedArray, n_actions: int | None, where: Where, source: str, traj_name: NameOf
) -> tuple[np.ndarray, int]:
    """The ``valid`` lists as a (rows, n) bool matrix, and n (their length)."""
    if vcol.null_count:
        raise row_error(
            where,
            "valid",
            first_null(vcol),
            "is empty (null); every row needs a list of booleans",
        )
    sizes = pc.list_value_length(vcol).to_numpy(zero_copy_only=False)
    width = n_actions if n_actions is not None else int(sizes[0])
    if not 1 <= width <= MAX_ACTIONS:
        raise row_error(where, "valid", 0, f"{width} entries; a valid list needs 1..{MAX_ACTIONS}")
    if (sizes != width).any():
        row = int(np.flatnonzero(sizes != width)[0])
        raise row_error(
            where, "valid", row, f"{int(sizes[row])} entries, expected {width} (one per action)"
        )
    entries = pc.list_flatten(vcol)
    if entries.null_count:  # every list has `width` entries: entry i is in row i // width
        row = first_null(entries) // width
        raise row_error(
            where,
            "valid",
            row,
            f"a null entry in the list (trajectory {traj_name(row)}); every "
            f"entry must be true or false",
        )
    check_action_memory(len(vcol), width, source, action_origin(n_actions, valid=True))
    return bool_lists(vcol, width, source), width


def count_actions(actions: np.ndarray, n_actions: int | None, where: Where, source: str) -> int:
    """The number of actions without ``valid`` lists: as configured, else the largest + 1 (with a
    warning when some are never taken: a stray large id widens every agent)."""
    rows = len(actions)
    n = n_actions if n_actions is not None else int(actions.max()) + 1
    if n < 1 or n > MAX_ACTIONS:  # before counting the actions: a stray id of 10**12 is no width
        raise DataError(f"{source}: {n} actions; pcpg handles 1..{MAX_ACTIONS}")
    check_action_memory(rows, n, source, action_origin(n_actions, valid=False))
    taken = np.bincount(actions[actions >= 0], minlength=n)[:n] if rows else np.zeros(0, np.int64)
    never = np.flatnonzero(taken == 0)
    if n_actions is None and len(never) and n > 1:
        top = int(np.flatnonzero(actions == n - 1)[0])
        logging.getLogger(__name__).warning(
            "%s: %d of the %d actions (%s) are never taken; their number comes from the largest "
            "action, %d (%s): set trajectories.n_actions if that is not right",
            where.locate(top)[0],
            len(never),
            n,
            reprlib.repr(never.tolist()),
            n - 1,
            f"row {where.locate(top)[1]}",
        )
    return n


def check_actions_in_range(
    groups: Trajectories,
    actions: np.ndarray,
    a_sorted: np.ndarray,
    valid: np.ndarray | None,
    n: int,
    n_actions: int | None,
    where: Where,
) -> None:
    """Every action is below n and, with masks, valid in its row."""
    order = groups.order
    too_big = a_sorted >= n
    if too_big.any():
        row = int(order[np.flatnonzero(too_big)[0]])
        raise row_error(
            where,
            "action",
            row,
            f"action {actions[row]} is outside 0..{n - 1} "
            f"({action_origin(n_actions, valid is not None)})",
        )
    if valid is not None:
        taken = a_sorted >= 0
        ok = np.ones(len(actions), bool)
        ok[taken] = valid[order[taken], a_sorted[taken]]
        if not ok.all():
            row = int(order[np.flatnonzero(~ok)[0]])
            raise row_error(
                where, "action", row, f"action {actions[row]} is not in the row's valid mask"
            )
