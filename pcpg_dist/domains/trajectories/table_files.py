"""Reading a user's step table from disk: one Parquet file, or a folder of them read as one.

Where a row came from (the file and its own row) is kept with the table, so every message of the
checks that follow (:mod:`.table_columns`, :mod:`.table`) names the file and row the user can open.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from pcpg_dist.common.errors import DataError, first_line
from pcpg_dist.dataset import check_parquet_memory, unreadable_parquet

MAX_FILES = 10_000
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
class Where:
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
    case of an extension says nothing about the content). The input policy applies
    (:mod:`pcpg_dist.common.inputs`): a link in the folder to a file outside it, or a FIFO, socket
    or device named ``*.parquet``, is one line, never read and never skipped in silence."""
    from pcpg_dist.common.inputs import entries

    if path.is_dir():
        files = entries(path, "step table", suffixes=[".parquet"])
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


def unreadable(f: Path, e: Exception) -> DataError:
    return unreadable_parquet(f, e, READS)


def check_same_columns(first: Path, schema: pa.Schema, f: Path, other: pa.Schema) -> None:
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
            raise unreadable(f, e) from None
        check_same_columns(files[0], schemas[0], f, schemas[-1])
    tables = []
    for f in files:
        try:
            tables.append(pq.read_table(f))
        except (pa.ArrowException, OSError) as e:
            raise unreadable(f, e) from None
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
