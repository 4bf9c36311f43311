"""The engine's side of the streamed pipeline: its settings, reading the log in blocks, summing
per-block vectors, and errors raised inside block functions brought back as themselves."""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import inspect
import json
import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np

from pcpg_dist.common.errors import pcpg_error_in
from pcpg_dist.domains.base import StreamSource
from pcpg_dist.orchestration.nodes import on_driver_node

ROWS_PER_BLOCK = 250_000  # steps per block of a source without parts (a few tens of MB)


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


def map_blocks(ds, fn: Callable, **kwargs):
    """``ds.map_batches(fn)`` on numpy batches, with the worker's freed memory handed back to the
    system after every call. A worker keeps the heap of its largest block (Arrow's pool and
    malloc's arenas) while it idles: measured, an idle worker held 0.8-1.1 GB through the BC
    step of a million-trajectory run, and 0.55 GB with this."""
    kwargs.setdefault("batch_format", "numpy")
    return ds.map_batches(_released(fn), **kwargs)


def _released(fn: Callable) -> Callable:
    @functools.wraps(fn)
    def run(*args, **kwargs):
        out = fn(*args, **kwargs)
        if not inspect.isgenerator(out):
            release_memory()
            return out

        def drained():
            yield from out
            release_memory()

        return drained()

    return run


@functools.cache
def _libc():
    try:  # find_library may say None: CDLL(None) is this process, glibc's symbols included
        lib = ctypes.CDLL(ctypes.util.find_library("c"))
    except OSError:
        return None
    return lib if hasattr(lib, "malloc_trim") else None  # glibc only


def release_memory() -> None:
    """Hand this process's freed memory back: Arrow's pool, then malloc's (glibc; a no-op
    elsewhere). A few milliseconds."""
    import pyarrow as pa

    pa.default_memory_pool().release_unused()
    libc = _libc()
    if libc is not None:
        libc.malloc_trim(0)


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
    """The log as a lazy ``ray.data`` dataset of the given columns.

    A source with ``parts`` (a local Parquet log's row groups, a local Minari dataset's runs of
    episodes) is read part by part by ``source.read_part`` in tasks kept on the driver's node
    where the cluster has others (no other node need see its disk); every later step runs
    anywhere. A source without parts (files on shared storage, URIs) goes through Ray Data's
    Parquet reader, on any node, in blocks of about :data:`ROWS_PER_BLOCK` steps."""
    import ray.data

    if source.parts:
        return _parts(source, columns, on_driver_node() or {})
    blocks = max(2, -(-source.steps // ROWS_PER_BLOCK))
    return ray.data.read_parquet(list(source.files), columns=columns, override_num_blocks=blocks)


def _parts(source: StreamSource, columns: list[str], options: dict):
    """``source.parts`` as the rows of a small dataset, each read by ``source.read_part`` in a
    task with ``options`` (e.g. kept on this node: Ray Data's own reader lists and samples the
    files in tasks no option keeps here, so a node without the driver's disk would fail)."""
    import ray.data

    read_part = source.read_part

    def read(batch: dict[str, np.ndarray]):
        for part in batch["part"]:
            yield from read_part(json.loads(part), columns)

    items = [{"part": json.dumps(part)} for part in source.parts]  # plain values, one column
    return map_blocks(ray.data.from_items(items), read, batch_size=1, **options)


def reduce_blocks(
    ds, fn: Callable[..., np.ndarray], combine: Callable = np.add, **kwargs
) -> np.ndarray:
    """``fn(block, **kwargs)`` (a float64 vector per block) combined over blocks (summed)."""

    def per_block(batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {"v": fn(batch, **kwargs)[None, :]}

    total = None
    for out in map_blocks(ds, per_block, batch_size=None).iter_batches(
        batch_format="numpy", batch_size=None
    ):
        for part in out["v"]:
            total = part if total is None else combine(total, part)
    return total
