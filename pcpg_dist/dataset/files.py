"""Datasets on disk: one Parquet file per environment and a manifest with a SHA-256 per file.

Every write is atomic (a crash never leaves a half file) and every read checks what it reads
against the manifest and its memory cost before decoding, so a dataset folder is either what
``pcpg generate`` wrote or one line saying what differs.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pcpg_dist.common.errors import DataError, first_line
from pcpg_dist.common.files import FILE_MODE, atomic_write_bytes, confined, sha256_file, temp_beside
from pcpg_dist.dataset.columns import SCHEMA_VERSION
from pcpg_dist.dataset.model import Dataset

MANIFEST = "manifest.json"
MAX_MANIFEST_BYTES = 64 << 20  # a manifest lists files and a config: kilobytes


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
