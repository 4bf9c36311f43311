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
order); nothing is written before the whole table has passed.
"""

from __future__ import annotations

import logging
import re
import reprlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from pcpg_dist.common.errors import DataError, first_line
from pcpg_dist.dataset import (
    MAX_ACTIONS,
    MAX_STYLES,
    Dataset,
    bool_lists,
    check_action_memory,
    check_parquet_memory,
    unreadable_parquet,
)

DOMAIN = "trajectories"
REQUIRED = ("trajectory", "t", "action")
RESERVED = {"trajectory", "t", "action", "reward", "valid", "env", "style", "success"}
STATE = re.compile(r"s(0|[1-9][0-9]*)")  # s0, s1, ...; "s01" is not s1; ASCII digits only
STATE_LIKE = re.compile(
    r"s\d+"
)  # any Unicode digits: refused below unless STATE, never read as another
MAX_FILES = 10_000
MAX_ENVS = 10_000  # each env is an evaluation unit with its own clustering and models
READS = "trajectories.path reads Parquet (a file or a folder of them) or minari:DATASET_ID"


@dataclass(frozen=True)
class StepTable:
    """A step table as read from disk, with where it came from (for messages).

    ``parts`` lists, for a folder, each file and its number of rows (in the table's order), so
    that a row of the combined table can be named as a file and its own row."""

    table: pa.Table
    source: str
    default_env: str
    parts: tuple[tuple[str, int], ...] = ()


@dataclass(frozen=True)
class _Where:
    """The source named in messages; rows of a folder's combined table map back to file and row."""

    source: str
    parts: tuple[tuple[str, int], ...] = ()

    def __str__(self) -> str:
        return self.source

    def locate(self, row: int) -> tuple[str, int]:
        for file, n in self.parts:
            if row < n:
                return file, row
            row -= n
        return self.source, row


def safe_env_name(text: str) -> str:
    """An env value made safe as a folder and file name (it becomes one)."""
    name = re.sub(r"[^A-Za-z0-9_.+-]", "_", str(text)).strip("._") or "env"
    return name[:100]


def parquet_files(path: Path) -> list[Path]:
    """A Parquet file, or the ``*.parquet`` files of a folder in name order (``.PARQUET`` too: the
    case of an extension says nothing about the content). A link in the folder to a file outside
    it is refused, as a dataset manifest's is: the folder is what the config names."""
    if path.is_dir():
        named = sorted(p for p in path.iterdir() if p.suffix.lower() == ".parquet")
        root = path.resolve()
        for p in named:
            if p.is_symlink() and not p.resolve().is_relative_to(root):
                raise DataError(
                    f"{p}: a link to {p.resolve()}, outside {path}; refusing to read it "
                    f"(copy the file into the folder)"
                )
        files = [p for p in named if p.is_file()]
        if not files:
            raise DataError(f"{path}: no .parquet files in this folder")
        if len(files) > MAX_FILES:
            raise DataError(f"{path}: {len(files)} Parquet files (at most {MAX_FILES}); merge them")
        return files
    if not path.is_file():
        if path.exists():  # a FIFO, device or socket: reading it would block or never end
            raise DataError(
                f"{path}: not a regular file or folder; trajectories.path names a Parquet file "
                f"or a folder of them"
            )
        raise DataError(f"{path}: no such file or folder (key trajectories.path)")
    return [path]


def _unreadable(f: Path, e: Exception) -> DataError:
    return unreadable_parquet(f, e, READS)


def _check_same_columns(first: Path, schema: pa.Schema, f: Path, other: pa.Schema) -> None:
    """A folder's file ``f`` has the columns of its first file, of types that combine."""
    types, other_types = (
        dict(zip(schema.names, schema.types, strict=True)),
        dict(zip(other.names, other.types, strict=True)),
    )
    same = "; every file of a folder needs the same columns"
    for name in schema.names:
        if name not in other_types:
            raise DataError(f"{f}: has no column '{name}', which {first.name} has{same}")
    for name in other.names:
        if name not in types:
            raise DataError(f"{f}: column '{name}' is not in {first.name}{same}")
        a, b = types[name], other_types[name]
        if a != b:
            try:
                pa.unify_schemas(
                    [pa.schema([(name, a)]), pa.schema([(name, b)])], promote_options="permissive"
                )
            except pa.ArrowException:
                raise DataError(
                    f"{f}: column '{name}' has type {b}, but {a} in {first.name}{same} "
                    f"of compatible types"
                ) from None


def read_step_table(path: str | Path) -> StepTable:
    """Read a Parquet file or a folder of them (each file's columns must be the first file's)."""
    path = Path(path)
    files = parquet_files(path)
    check_parquet_memory(files, str(path), READS)
    schemas = []
    for f in files:  # footers only: a file that differs is named before any data is read
        try:
            schemas.append(pq.read_schema(f))
        except (pa.ArrowException, OSError) as e:
            raise _unreadable(f, e) from None
        _check_same_columns(files[0], schemas[0], f, schemas[-1])
    tables = []
    for f in files:
        try:
            tables.append(pq.read_table(f))
        except (pa.ArrowException, OSError) as e:
            raise _unreadable(f, e) from None
    try:
        table = (
            pa.concat_tables(tables, promote_options="permissive") if len(tables) > 1 else tables[0]
        )
    except pa.ArrowException as e:
        raise DataError(
            f"{path}: the Parquet files' columns do not agree ({first_line(e)})"
        ) from None
    parts = (
        tuple((str(f), t.num_rows) for f, t in zip(files, tables, strict=True))
        if len(files) > 1
        else ()
    )
    return StepTable(
        table, str(path), safe_env_name(path.stem if path.is_file() else path.name), parts
    )


def _fail(where: _Where, column: str, row: int, what: str) -> DataError:
    file, row = where.locate(row)
    return DataError(f"{file}: column '{column}', row {row}: {what}")


def _first_null(col: pa.ChunkedArray) -> int:
    return int(np.flatnonzero(col.is_null().to_numpy(zero_copy_only=False))[0])


# ------------------------------------------------------------------ column types, before any cast
def _is_number(t: pa.DataType) -> bool:
    return pa.types.is_integer(t) or pa.types.is_floating(t) or pa.types.is_boolean(t)


def _is_integral(t: pa.DataType) -> bool:
    return pa.types.is_integer(t) or pa.types.is_floating(t)


def _is_text(t: pa.DataType) -> bool:
    return (
        pa.types.is_string(t)
        or pa.types.is_large_string(t)
        or pa.types.is_binary(t)
        or pa.types.is_large_binary(t)
    )


def _is_bool_list(t: pa.DataType) -> bool:
    return (
        pa.types.is_list(t) or pa.types.is_large_list(t) or pa.types.is_fixed_size_list(t)
    ) and pa.types.is_boolean(t.value_type)


def _plain(t: pa.DataType) -> pa.DataType:
    return t.value_type if pa.types.is_dictionary(t) else t


#: what each reserved column may hold: (in words, test of its Arrow type)
COLUMN_TYPES = {
    "trajectory": ("integers or strings", lambda t: _is_integral(_plain(t)) or _is_text(_plain(t))),
    "t": ("integers", _is_integral),
    "action": ("integers", _is_integral),
    "style": ("integers", _is_integral),
    "env": ("strings or integers", lambda t: pa.types.is_integer(_plain(t)) or _is_text(_plain(t))),
    "valid": ("a list of booleans per row", _is_bool_list),
    "reward": ("numbers", _is_number),
    "success": ("booleans or numbers", _is_number),
}


def check_column_types(
    schema: pa.Schema, s_cols: list[str], skill_column: str | None, source: str
) -> None:
    """Every column pcpg reads has a type it can read (a column of nulls passes: its rows are named
    later); a DataError naming the column and the allowed types otherwise."""
    wanted = dict(COLUMN_TYPES)
    wanted.update(
        {c: ("numbers", _is_number) for c in [*s_cols, *([skill_column] if skill_column else [])]}
    )
    for name, t in zip(schema.names, schema.types, strict=True):
        if name in wanted and not pa.types.is_null(t) and not wanted[name][1](t):
            raise DataError(f"{source}: column '{name}' has type {t}; expected {wanted[name][0]}")


def _integers(col: pa.ChunkedArray, name: str, where: _Where) -> np.ndarray:
    """An integer column as int64 (integral floats accepted); nulls, fractions, NaN and values that
    int64 cannot hold rejected."""
    if col.null_count:
        raise _fail(where, name, _first_null(col), "is empty (null); every row needs a value")
    if pa.types.is_integer(col.type):
        x = col.to_numpy()
        if x.dtype == np.uint64 and (x > np.iinfo(np.int64).max).any():
            row = int(np.flatnonzero(x > np.iinfo(np.int64).max)[0])
            raise _fail(where, name, row, f"{int(x[row])} does not fit a 64-bit signed integer")
        return x.astype(np.int64)
    if pa.types.is_floating(col.type):
        x = col.to_numpy()
        bad = ~np.isfinite(x) | (x != np.round(x)) | (np.abs(x) > 2**53)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise _fail(where, name, row, f"{float(x[row])} is not an integer")
        return x.astype(np.int64)
    raise DataError(f"{where}: column '{name}' has type {col.type}; expected integers")


def _numeric(table: pa.Table, name: str, where: _Where) -> pa.ChunkedArray:
    """A column that must hold numbers (or booleans) in every row."""
    col = table.column(name)
    if col.null_count:
        raise _fail(where, name, _first_null(col), "is empty (null); every row needs a value")
    if not _is_number(col.type):
        raise DataError(f"{where}: column '{name}' has type {col.type}; expected numbers")
    return col


def _floats(table: pa.Table, name: str, where: _Where) -> np.ndarray:
    x = _numeric(table, name, where).to_numpy(zero_copy_only=False).astype(np.float64)
    if not np.isfinite(x).all():
        row = int(np.flatnonzero(~np.isfinite(x))[0])
        raise _fail(where, name, row, f"{x[row]} is not a finite number")
    return x


def _state_matrix(table: pa.Table, s_cols: list[str], where: _Where) -> np.ndarray:
    """The state columns as one float32 matrix; nulls, NaN, infinities and overflow rejected."""
    states = np.empty((table.num_rows, len(s_cols)), np.float32)
    for j, c in enumerate(s_cols):
        col = _numeric(table, c, where)
        with np.errstate(over="ignore", invalid="ignore"):
            states[:, j] = col.to_numpy(zero_copy_only=False)  # float64 beyond float32 becomes inf
    bad = ~np.isfinite(states)
    if bad.any():
        row, j = (int(v[0]) for v in np.nonzero(bad))
        raw = table.column(s_cols[j])[row].as_py()
        raise _fail(where, s_cols[j], row, f"{raw} is not a finite 32-bit float")
    return states


def _per_trajectory(
    values: np.ndarray, starts: np.ndarray, order: np.ndarray, name: str, where: _Where
) -> np.ndarray:
    """A column that must be constant within each trajectory, one value per trajectory."""
    v = values[order]
    first = np.repeat(v[starts], np.diff(np.r_[starts, len(v)]))
    differs = v != first
    if differs.any():
        row = int(order[np.flatnonzero(differs)[0]])
        raise _fail(
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


def _codes(col: pa.ChunkedArray) -> tuple[np.ndarray, list]:
    """Each row's index into the column's distinct values, and those values."""
    if pa.types.is_dictionary(col.type):
        col = col.cast(col.type.value_type)
    enc = pc.dictionary_encode(col).combine_chunks()
    return enc.indices.to_numpy(zero_copy_only=False).astype(np.int64), enc.dictionary.to_pylist()


def _action_origin(n_actions: int | None, valid: bool) -> str:
    """Where the number of actions came from, for a message."""
    if n_actions is not None:
        return "trajectories.n_actions"
    return "the length of the valid lists" if valid else "the largest action + 1"


def datasets_from_table(
    step: StepTable, n_actions: int | None = None, skill_column: str | None = None
) -> dict[str, Dataset]:
    """Validate a step table and cut it into one Dataset per ``env`` value (see the module doc)."""
    table, source = step.table, step.source
    where = _Where(source, step.parts)
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
    rows = table.num_rows
    if rows == 0:
        raise DataError(f"{source}: the table has no rows")
    check_column_types(table.schema, s_cols, skill_column, source)

    # trajectory ids (int or string) -> codes; env values -> units
    traj_col = table.column("trajectory")
    if traj_col.null_count:
        raise _fail(where, "trajectory", _first_null(traj_col), "is empty (null)")
    id_names = None  # the user's ids by number, where they are not integers
    if _is_integral(traj_col.type):
        traj_raw = _integers(traj_col, "trajectory", where)
    else:  # strings, bytes (compared as bytes: they need not be UTF-8) or a dictionary of them
        code, ids = _codes(traj_col)
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

    def traj_name(row: int) -> str:
        return reprlib.repr(
            int(traj_raw[row]) if _is_integral(traj_col.type) else traj_col[row].as_py()
        )

    if "env" in names:
        env_col = table.column("env")
        if env_col.null_count:
            raise _fail(where, "env", _first_null(env_col), "is empty (null)")
        env_code, env_values = _codes(env_col)
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
                    raise _fail(
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
    else:
        env_code, env_names = np.zeros(rows, np.int64), [step.default_env]

    t = _integers(table.column("t"), "t", where)
    actions = _integers(table.column("action"), "action", where)
    # group rows by (env, trajectory) and order them by t (rows of one t: file order, named below)
    order = np.lexsort((np.arange(rows), t, traj_raw, env_code))
    key_env, key_traj = env_code[order], traj_raw[order]
    new = np.r_[True, (np.diff(key_traj) != 0) | (np.diff(key_env) != 0)]
    starts = np.flatnonzero(new)
    ends = np.r_[starts[1:], rows]
    t_sorted = t[order]
    repeated = np.r_[False, np.diff(t_sorted) == 0] & ~new
    # a trajectory may go on into a later file of a folder, its t going on too; a later file whose t
    # starts below an earlier file's is a restart: another trajectory under the same id
    file_of = (
        np.repeat(np.arange(len(where.parts)), [n for _, n in where.parts])
        if where.parts
        else np.zeros(rows, np.int64)
    )[order]
    back = np.r_[False, np.diff(file_of) < 0] & ~new
    if (repeated | back).any():
        at = int(np.flatnonzero(repeated | back)[0])
        row, previous = int(order[at]), int(order[at - 1])  # two rows of one trajectory, in t order
        (file, i), (prev_file, j) = where.locate(row), where.locate(previous)
        if file != prev_file:  # daily files whose ids restart at 0: not a t problem
            g = np.searchsorted(starts, at, side="right") - 1
            group = np.arange(starts[g], ends[g])  # the trajectory's rows, in t order
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

    # actions: 0..n-1, -1 allowed only on a trajectory's last row
    a_sorted = actions[order]
    last = np.zeros(rows, bool)
    last[ends - 1] = True
    neg = (a_sorted < 0) & ~(last & (a_sorted == -1))
    if neg.any():
        row = int(order[np.flatnonzero(neg)[0]])
        raise _fail(
            where,
            "action",
            row,
            f"action {actions[row]} is not allowed (0..n-1; -1 only on a trajectory's last row)",
        )
    if (a_sorted == -1).all():  # only closing rows: no state is followed by an action
        raise DataError(
            f"{source}: no trajectory has a step: each of the {len(starts)} trajectories is a "
            f"single row (action -1, its closing state); a trajectory needs rows with actions "
            f"0..n-1 before its last"
        )
    valid = None
    if "valid" in names:
        vcol = table.column("valid")
        if vcol.null_count:
            raise _fail(
                where,
                "valid",
                _first_null(vcol),
                "is empty (null); every row needs a list of booleans",
            )
        sizes = pc.list_value_length(vcol).to_numpy(zero_copy_only=False)
        width = n_actions if n_actions is not None else int(sizes[0])
        if not 1 <= width <= MAX_ACTIONS:
            raise _fail(where, "valid", 0, f"{width} entries; a valid list needs 1..{MAX_ACTIONS}")
        if (sizes != width).any():
            row = int(np.flatnonzero(sizes != width)[0])
            raise _fail(
                where, "valid", row, f"{int(sizes[row])} entries, expected {width} (one per action)"
            )
        entries = pc.list_flatten(vcol)
        if entries.null_count:  # every list has `width` entries: entry i is in row i // width
            row = _first_null(entries) // width
            raise _fail(
                where,
                "valid",
                row,
                f"a null entry in the list (trajectory {traj_name(row)}); every "
                f"entry must be true or false",
            )
        check_action_memory(rows, width, source, _action_origin(n_actions, valid=True))
        valid = bool_lists(vcol, width, source)
        n = width
    else:
        n = n_actions if n_actions is not None else int(actions.max()) + 1
        if (
            n < 1 or n > MAX_ACTIONS
        ):  # before counting the actions: a stray id of 10**12 is no width
            raise DataError(f"{source}: {n} actions; pcpg handles 1..{MAX_ACTIONS}")
        check_action_memory(rows, n, source, _action_origin(n_actions, valid=False))
        taken = (
            np.bincount(actions[actions >= 0], minlength=n)[:n] if rows else np.zeros(0, np.int64)
        )
        never = np.flatnonzero(taken == 0)
        if n_actions is None and len(never) and n > 1:  # a stray large action id widens every agent
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
    too_big = a_sorted >= n
    if too_big.any():
        row = int(order[np.flatnonzero(too_big)[0]])
        raise _fail(
            where,
            "action",
            row,
            f"action {actions[row]} is outside 0..{n - 1} "
            f"({_action_origin(n_actions, valid is not None)})",
        )
    if valid is not None:
        taken = a_sorted >= 0
        ok = np.ones(rows, bool)
        ok[taken] = valid[order[taken], a_sorted[taken]]
        if not ok.all():
            row = int(order[np.flatnonzero(~ok)[0]])
            raise _fail(
                where, "action", row, f"action {actions[row]} is not in the row's valid mask"
            )

    # states, rewards, per-trajectory columns
    states = _state_matrix(table, s_cols, where)
    rewards = _floats(table, "reward", where) if "reward" in names else np.zeros(rows)
    styles = (
        _per_trajectory(
            _integers(table.column("style"), "style", where), starts, order, "style", where
        )
        if "style" in names
        else np.full(len(starts), -1, np.int64)
    )
    if ((styles < -1) | (styles >= MAX_STYLES)).any():
        bad = int(np.flatnonzero((styles < -1) | (styles >= MAX_STYLES))[0])
        raise _fail(
            where,
            "style",
            int(order[starts[bad]]),
            f"style {styles[bad]}; styles are 0, 1, 2, ... (below {MAX_STYLES}), or -1 for unknown",
        )
    success = (
        _per_trajectory(_floats(table, "success", where) != 0, starts, order, "success", where)
        if "success" in names
        else np.ones(len(starts), bool)
    )
    skill = (
        _per_trajectory(_floats(table, skill_column, where), starts, order, skill_column, where)
        if skill_column is not None
        else None
    )

    # closing rows: a trajectory whose last row has an action ends on a repeat of its last state
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
    with np.errstate(over="ignore", invalid="ignore"):  # the returns Step B ranks by: reported here
        returns = np.add.reduceat(all_rewards, offsets[:-1])
    if not np.isfinite(returns).all():
        i = int(np.flatnonzero(~np.isfinite(returns))[0])
        lo, hi = offsets[i], offsets[i + 1]
        row = int(src[lo + np.argmax(np.abs(all_rewards[lo:hi]))])
        raise _fail(
            where,
            "reward",
            row,
            f"the rewards of trajectory {traj_name(row)} add up beyond a 64-bit "
            f"float (the largest, {rewards[row]:g}, is in this row); scale the "
            f"rewards down so that each trajectory's sum is finite",
        )
    traj_env = key_env[starts]
    traj_ids = key_traj[starts]
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
            states=all_states[lo:hi],
            actions=all_actions[lo:hi],
            valid=np.ascontiguousarray(all_valid[lo:hi]),
            rewards=all_rewards[lo:hi],
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
