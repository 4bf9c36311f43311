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

from pcpg_dist.dataset.columns import (
    MAX_ACTIONS,
    MAX_STYLES,
    SCHEMA_VERSION,
    bool_lists,
    check_action_memory,
)
from pcpg_dist.dataset.files import (
    MANIFEST,
    check_parquet_memory,
    content_digest,
    file_name,
    load_dataset,
    load_datasets,
    read_manifest,
    read_parquet,
    unreadable_parquet,
    write_datasets,
    write_parquet,
)
from pcpg_dist.dataset.model import Dataset

__all__ = [
    "MANIFEST",
    "MAX_ACTIONS",
    "MAX_STYLES",
    "SCHEMA_VERSION",
    "Dataset",
    "bool_lists",
    "check_action_memory",
    "check_parquet_memory",
    "content_digest",
    "file_name",
    "load_dataset",
    "load_datasets",
    "read_manifest",
    "read_parquet",
    "unreadable_parquet",
    "write_datasets",
    "write_parquet",
]
