"""The numba engine of Step C: packs the cells' rows for the compiled kernel and unpacks its result.

Why its own module: the kernel (:mod:`pcpg_dist.stages.bc.kernel`) takes flat, contiguous arrays
and offsets; turning cells into that layout (and the minibatch shuffle, and the threads' share of
the cells) is plain NumPy that the kernel should not carry.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch

from pcpg_dist.config.stages import BCConfig
from pcpg_dist.stages.bc.network import INVALID_LOGIT
from pcpg_dist.stages.legal_share import few_legal
from pcpg_dist.stages.ranking import Cell


def _thread_schedule(rows: Sequence[int], slots: int) -> tuple[np.ndarray, np.ndarray]:
    """Longest-first assignment of cells to thread slots, so no thread idles while one works."""
    load = [0] * slots
    bins: list[list[int]] = [[] for _ in range(slots)]
    for i in sorted(range(len(rows)), key=lambda i: -rows[i]):
        t = int(np.argmin(load))
        bins[t].append(i)
        load[t] += rows[i] + 50  # + a fixed per-cell cost
    return (
        np.array([i for b in bins for i in b], np.int64),
        np.r_[0, np.cumsum([len(b) for b in bins])].astype(np.int64),
    )


#: ``bc.batch_size: auto``: a cell of more distinct rows than this trains in minibatches of
#: AUTO_BATCH rows (full batch below: every cell of the paper's three domains)
AUTO_FULL_BATCH_ROWS = 20_000
AUTO_BATCH = 4096


def cell_batches(rows: Sequence[int], cfg: BCConfig) -> tuple[np.ndarray, np.ndarray]:
    """Each cell's rows per Adam step (0: full batch) and passes over its rows.

    ``batch_size: auto`` keeps full batch (the paper) up to AUTO_FULL_BATCH_ROWS distinct rows
    and gives larger cells minibatches of AUTO_BATCH rows with the same budget of Adam steps
    (``bc.epochs``): full batch over a continuous log's hundreds of thousands of distinct rows
    took ~100x the compute to reach the same loss (docs/bc_and_evaluation.md). An explicit
    ``batch_size`` applies to every cell, and ``epochs`` are then passes over the rows.
    """
    rows = np.asarray(rows, np.int64)
    if cfg.batch_size is None:
        return np.zeros(len(rows), np.int64), np.full(len(rows), cfg.epochs, np.int64)
    if cfg.batch_size != "auto":
        return np.full(len(rows), cfg.batch_size, np.int64), np.full(
            len(rows), cfg.epochs, np.int64
        )
    big = rows > AUTO_FULL_BATCH_ROWS
    batch = np.where(big, AUTO_BATCH, 0)
    blocks = -(-rows // AUTO_BATCH)
    passes = np.where(big, -(-cfg.epochs // np.maximum(blocks, 1)), cfg.epochs)
    return batch.astype(np.int64), passes.astype(np.int64)


def output_masks(
    valid: np.ndarray, acts: np.ndarray, pairs: bool | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kernel's view of the valid masks (R, A): (neg (A, R), pair_off, pair_act).

    Dense: neg is 0 or INVALID_LOGIT per action and row, no pairs. Legal pairs (``pairs``, or
    where few_legal when None): neg is (0, R) and row r's legal actions are
    pair_act[pair_off[r]:pair_off[r + 1]]; a taken action always counts as legal (a log whose
    mask disagrees with its actions then trains as if the mask allowed it)."""
    rows, n_actions = valid.shape
    if pairs is None:
        pairs = few_legal(n_actions, int(valid.sum()), rows)
    if not pairs:
        neg = np.where(valid.T, np.float32(0.0), np.float32(INVALID_LOGIT))
        none = np.zeros(0, np.int64)
        return np.ascontiguousarray(neg, np.float32), none, none
    allowed = valid.copy()
    allowed[np.arange(rows), acts] = True
    row, action = np.nonzero(allowed)  # row by row, actions ascending
    pair_off = np.searchsorted(row, np.arange(rows + 1)).astype(np.int64)
    return np.zeros((0, rows), np.float32), pair_off, action.astype(np.int64)


def _shuffled(rows: tuple[np.ndarray, ...], seed: int) -> tuple[np.ndarray, ...]:
    """A minibatched cell's rows in one fixed order drawn from its seed: its blocks."""
    order = np.random.default_rng([seed, 1]).permutation(len(rows[2]))
    return tuple(a[order] for a in rows)


def train_numba(
    cells: Sequence[Cell],
    data: list[tuple[np.ndarray, ...]],
    sizes: tuple[int, ...],
    cfg: BCConfig,
    starts: list[np.ndarray],
    pairs: bool | None = None,
) -> tuple[dict, np.ndarray, np.ndarray]:
    """Train every cell with the compiled kernel on this process's threads; (parameters by
    name, final loss per cell, Adam steps per cell), as
    :func:`~pcpg_dist.stages.bc.torch_engine.train_group`. ``pairs``: compute the output layer
    at the legal pairs only (None: where :func:`~pcpg_dist.stages.legal_share.few_legal`)."""
    from pcpg_dist.stages.bc.kernel import train_kernel

    batch, epochs = cell_batches([len(x[2]) for x in data], cfg)
    data = [
        x if b == 0 else _shuffled(x, c.spec.seed)
        for c, x, b in zip(cells, data, batch, strict=True)
    ]
    rows = [len(x[2]) for x in data]
    row_off = np.r_[0, np.cumsum(rows)].astype(np.int64)
    xt = np.concatenate([(s - c.mean) / c.std for c, (s, _, _, _) in zip(cells, data, strict=True)])
    acts = np.concatenate([a for _, _, a, _ in data]).astype(np.int64)
    neg, pair_off, pair_act = output_masks(np.concatenate([v for _, v, _, _ in data]), acts, pairs)
    wn = np.concatenate([w / w.sum() for _, _, _, w in data]).astype(np.float32)
    theta = np.stack(starts).astype(np.float32)
    numel = [x for a, b in zip(sizes[:-1], sizes[1:], strict=True) for x in (a * b, b)]
    offs = np.r_[0, np.cumsum(numel)].astype(np.int64)
    # follow the thread count the caller gave torch (parallel.set_threads): more threads than
    # the CPUs this process was given wait for their slowest one
    slots = max(1, min(torch.get_num_threads(), len(cells)))
    schedule, sched_off = _thread_schedule(
        [r * e for r, e in zip(rows, epochs, strict=True)], slots
    )
    losses, steps = np.zeros(len(cells)), np.zeros(len(cells), np.int64)
    args = (
        np.ascontiguousarray(xt.T, np.float32),
        neg,
        acts,
        wn,
        row_off,
        theta,
        np.array(sizes, np.int64),
        offs[0:-1:2].copy(),
        offs[1::2].copy(),
        epochs,
        cfg.lr,
        cfg.betas[0],
        cfg.betas[1],
        cfg.eps,
        cfg.activation == "relu",
    )
    tail = (
        batch,
        cfg.stop_window if cfg.stop_tol > 0 else 0,
        cfg.stop_tol,
        steps,
        pair_off,
        pair_act,
    )
    shares = [schedule[a:b] for a, b in itertools.pairwise(sched_off)]
    with ThreadPoolExecutor(slots) as pool:  # the kernel releases the GIL: a thread per share
        list(pool.map(lambda share: train_kernel(*args, share, losses, *tail), shares))
    out = {}
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        out[f"W{i}"] = theta[:, offs[2 * i] : offs[2 * i + 1]].reshape(-1, a, b).copy()
        out[f"b{i}"] = theta[:, offs[2 * i + 1] : offs[2 * i + 2]].copy()
    return out, losses, steps
