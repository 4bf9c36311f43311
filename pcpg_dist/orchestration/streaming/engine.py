"""The engine's side of the streamed pipeline: its settings, reading the log in blocks, summing
per-block vectors, and errors raised inside block functions brought back as themselves."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np

from pcpg_dist.common.errors import pcpg_error_in
from pcpg_dist.domains.base import StreamSource
from pcpg_dist.orchestration.nodes import on_driver_node

ROWS_PER_BLOCK = 250_000  # steps per read block (a few tens of MB of state)


def quiet_engine() -> None:
    """Blocks in a fixed order (the same seed gives the same numbers: the BC cells see their
    rows in the same order), and no Ray Data progress bars or info lines: pcpg prints its own."""
    import ray.data

    ctx = ray.data.DataContext.get_current()
    ctx.execution_options.preserve_order = True
    # a shuffle's map task takes up to 1 GiB of blocks by default: one task holding a million
    # trajectories' partial sums at once measured 3.9 GB; 64 MiB keeps each map task small
    ctx.shuffle_input_batch_bytes = 64 * 2**20
    ctx.enable_progress_bars = False
    ctx.print_on_execution_start = False
    logging.getLogger("ray.data").setLevel(logging.ERROR)


@contextmanager
def engine_errors() -> Iterator[None]:
    """A :class:`PcpgError` raised inside a block function or task reaches the user as itself."""
    try:
        yield
    except Exception as e:  # noqa: BLE001 - Ray wraps a UDF's exception in its own types
        found = pcpg_error_in(e)
        if found is None or found is e:
            raise
        raise found from None


def read_steps(source: StreamSource, columns: list[str]):
    """The log as a lazy ``ray.data`` dataset of the given columns, in blocks of about
    :data:`ROWS_PER_BLOCK` steps. On one node, or from shared storage (a URI), Ray Data's Parquet
    reader reads it anywhere. On a cluster, local files are read on the driver's node only (no
    other node need see its disk: :func:`_read_here`); every later step runs anywhere."""
    import ray.data

    pinned = None if any("://" in f for f in source.files) else on_driver_node()
    if pinned is not None:
        return _read_here(source, columns, pinned)
    blocks = max(2, -(-source.steps // ROWS_PER_BLOCK))
    return ray.data.read_parquet(list(source.files), columns=columns, override_num_blocks=blocks)


def _read_here(source: StreamSource, columns: list[str], options: dict):
    """The files' row groups as the rows of a small dataset, each read (in slices of
    :data:`ROWS_PER_BLOCK`) by a task kept on this node. Ray Data's own reader lists and samples
    the files in tasks no option keeps here, so a node without the driver's disk would fail."""
    import pyarrow.parquet as pq
    import ray.data

    groups = [
        {"file": f, "group": g}
        for f in source.files
        for g in range(pq.ParquetFile(f).metadata.num_row_groups)
    ]

    def read(batch: dict[str, np.ndarray]):
        for f, g in zip(batch["file"], batch["group"], strict=True):
            table = pq.ParquetFile(str(f)).read_row_group(int(g), columns=columns)
            for lo in range(0, table.num_rows, ROWS_PER_BLOCK):
                yield table.slice(lo, ROWS_PER_BLOCK)

    return ray.data.from_items(groups).map_batches(
        read, batch_size=1, batch_format="numpy", **options
    )


def reduce_blocks(
    ds, fn: Callable[..., np.ndarray], combine: Callable = np.add, **kwargs
) -> np.ndarray:
    """``fn(block, **kwargs)`` (a float64 vector per block) combined over blocks (summed)."""

    def per_block(batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {"v": fn(batch, **kwargs)[None, :]}

    total = None
    for out in ds.map_batches(per_block, batch_format="numpy", batch_size=None).iter_batches(
        batch_format="numpy", batch_size=None
    ):
        for part in out["v"]:
            total = part if total is None else combine(total, part)
    return total
