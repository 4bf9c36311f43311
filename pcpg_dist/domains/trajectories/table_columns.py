"""The step table's columns, read one at a time: types checked before any cast, each problem
one DataError naming the file, the column and the row.

A column's type is checked from the schema first (:func:`check_column_types`), then its values as
they are converted (nulls, fractions, NaN, values int64 or float32 cannot hold), so that
:func:`pcpg_dist.domains.trajectories.table.datasets_from_table` only orders and cuts rows.
"""

from __future__ import annotations

import re

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pcpg_dist.common.errors import DataError
from pcpg_dist.domains.trajectories.table_files import Where

STATE = re.compile(r"s(0|[1-9][0-9]*)")  # s0, s1, ...; "s01" is not s1; ASCII digits only
STATE_LIKE = re.compile(
    r"s\d+"
)  # any Unicode digits: refused below unless STATE, never read as another


def row_error(where: Where, column: str, row: int, what: str) -> DataError:
    file, row = where.locate(row)
    return DataError(f"{file}: column '{column}', row {row}: {what}")


def first_null(col: pa.ChunkedArray) -> int:
    return int(np.flatnonzero(col.is_null().to_numpy(zero_copy_only=False))[0])


# ------------------------------------------------------------------ column types, before any cast
def is_number(t: pa.DataType) -> bool:
    return pa.types.is_integer(t) or pa.types.is_floating(t) or pa.types.is_boolean(t)


def is_integral(t: pa.DataType) -> bool:
    return pa.types.is_integer(t) or pa.types.is_floating(t)


def is_text(t: pa.DataType) -> bool:
    return (
        pa.types.is_string(t)
        or pa.types.is_large_string(t)
        or pa.types.is_binary(t)
        or pa.types.is_large_binary(t)
    )


def is_bool_list(t: pa.DataType) -> bool:
    return (
        pa.types.is_list(t) or pa.types.is_large_list(t) or pa.types.is_fixed_size_list(t)
    ) and pa.types.is_boolean(t.value_type)


def plain(t: pa.DataType) -> pa.DataType:
    return t.value_type if pa.types.is_dictionary(t) else t


#: what each reserved column may hold: (in words, test of its Arrow type)
COLUMN_TYPES = {
    "trajectory": ("integers or strings", lambda t: is_integral(plain(t)) or is_text(plain(t))),
    "t": ("integers", is_integral),
    "action": ("integers", is_integral),
    "style": ("integers", is_integral),
    "env": ("strings or integers", lambda t: pa.types.is_integer(plain(t)) or is_text(plain(t))),
    "valid": ("a list of booleans per row", is_bool_list),
    "reward": ("numbers", is_number),
    "success": ("booleans or numbers", is_number),
}


def check_column_types(
    schema: pa.Schema, s_cols: list[str], skill_column: str | None, source: str
) -> None:
    """Every column pcpg reads has a type it can read (a column of nulls passes: its rows are named
    later); a DataError naming the column and the allowed types otherwise."""
    wanted = dict(COLUMN_TYPES)
    wanted.update(
        {c: ("numbers", is_number) for c in [*s_cols, *([skill_column] if skill_column else [])]}
    )
    for name, t in zip(schema.names, schema.types, strict=True):
        if name in wanted and not pa.types.is_null(t) and not wanted[name][1](t):
            raise DataError(f"{source}: column '{name}' has type {t}; expected {wanted[name][0]}")


def integers(col: pa.ChunkedArray, name: str, where: Where) -> np.ndarray:
    """An integer column as int64 (integral floats accepted); nulls, fractions, NaN and values that
    int64 cannot hold rejected."""
    if col.null_count:
        raise row_error(where, name, first_null(col), "is empty (null); every row needs a value")
    if pa.types.is_integer(col.type):
        x = col.to_numpy()
        if x.dtype == np.uint64 and (x > np.iinfo(np.int64).max).any():
            row = int(np.flatnonzero(x > np.iinfo(np.int64).max)[0])
            raise row_error(where, name, row, f"{int(x[row])} does not fit a 64-bit signed integer")
        return x.astype(np.int64)
    if pa.types.is_floating(col.type):
        x = col.to_numpy()
        bad = ~np.isfinite(x) | (x != np.round(x)) | (np.abs(x) > 2**53)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise row_error(where, name, row, f"{float(x[row])} is not an integer")
        return x.astype(np.int64)
    raise DataError(f"{where}: column '{name}' has type {col.type}; expected integers")


def numeric(table: pa.Table, name: str, where: Where) -> pa.ChunkedArray:
    """A column that must hold numbers (or booleans) in every row."""
    col = table.column(name)
    if col.null_count:
        raise row_error(where, name, first_null(col), "is empty (null); every row needs a value")
    if not is_number(col.type):
        raise DataError(f"{where}: column '{name}' has type {col.type}; expected numbers")
    return col


def floats(table: pa.Table, name: str, where: Where) -> np.ndarray:
    x = numeric(table, name, where).to_numpy(zero_copy_only=False).astype(np.float64)
    if not np.isfinite(x).all():
        row = int(np.flatnonzero(~np.isfinite(x))[0])
        raise row_error(where, name, row, f"{x[row]} is not a finite number")
    return x


def state_matrix(table: pa.Table, s_cols: list[str], where: Where) -> np.ndarray:
    """The state columns as one float32 matrix; nulls, NaN, infinities and overflow rejected."""
    states = np.empty((table.num_rows, len(s_cols)), np.float32)
    for j, c in enumerate(s_cols):
        col = numeric(table, c, where)
        with np.errstate(over="ignore", invalid="ignore"):
            states[:, j] = col.to_numpy(zero_copy_only=False)  # float64 beyond float32 becomes inf
    bad = ~np.isfinite(states)
    if bad.any():
        row, j = (int(v[0]) for v in np.nonzero(bad))
        raw = table.column(s_cols[j])[row].as_py()
        raise row_error(where, s_cols[j], row, f"{raw} is not a finite 32-bit float")
    return states


def per_trajectory(
    values: np.ndarray, starts: np.ndarray, order: np.ndarray, name: str, where: Where
) -> np.ndarray:
    """A column that must be constant within each trajectory, one value per trajectory."""
    v = values[order]
    first = np.repeat(v[starts], np.diff(np.r_[starts, len(v)]))
    differs = v != first
    if differs.any():
        row = int(order[np.flatnonzero(differs)[0]])
        raise row_error(
            where, name, row, "changes within a trajectory; it must be one value per trajectory"
        )
    return v[starts]


def state_columns(names: list[str], source: str) -> list[str]:
    odd = next((c for c in names if STATE_LIKE.fullmatch(c) and not STATE.fullmatch(c)), None)
    if odd is not None and not odd.isascii():
        raise DataError(
            f"{source}: column {odd!r} names a state with non-ASCII digits; state columns are "
            f"named s0, s1, ... s{{d-1}} with the digits 0-9"
        )
    if odd is not None:
        raise DataError(
            f"{source}: column '{odd}' has a leading zero; state columns are named s0, s1, ... "
            f"s{{d-1}} without leading zeros (rename it s{int(odd[1:])})"
        )
    idx = sorted(int(m.group(1)) for c in names if (m := STATE.fullmatch(c)))
    if not idx:
        raise DataError(
            f"{source}: no state columns; expected numeric columns s0, s1, ... s{{d-1}}"
        )
    if idx != list(range(len(idx))):
        gap = next(i for i, j in enumerate(idx) if i != j)
        raise DataError(
            f"{source}: state columns must be s0..s{{d-1}} without gaps; s{gap} is missing"
        )
    return [f"s{j}" for j in idx]


def codes(col: pa.ChunkedArray) -> tuple[np.ndarray, list]:
    """Each row's index into the column's distinct values, and those values."""
    if pa.types.is_dictionary(col.type):
        col = col.cast(col.type.value_type)
    enc = pc.dictionary_encode(col).combine_chunks()
    return enc.indices.to_numpy(zero_copy_only=False).astype(np.int64), enc.dictionary.to_pylist()


def action_origin(n_actions: int | None, valid: bool) -> str:
    """Where the number of actions came from, for a message."""
    if n_actions is not None:
        return "trajectories.n_actions"
    return "the length of the valid lists" if valid else "the largest action + 1"
