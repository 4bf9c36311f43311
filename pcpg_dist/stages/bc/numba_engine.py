"""The numba engine of Step C: packs the cells' rows for the compiled kernel and unpacks its result.

Why its own module: the kernel (:mod:`pcpg_dist.stages.bc.kernel`) takes flat, contiguous arrays
and offsets; turning cells into that layout (and the minibatch shuffle, and the threads' share of
the cells) is plain NumPy that the kernel should not carry.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from pcpg_dist.config.stages import BCConfig
from pcpg_dist.stages.bc.network import INVALID_LOGIT
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


def train_numba(
    cells: Sequence[Cell],
    data: list[tuple[np.ndarray, ...]],
    sizes: tuple[int, ...],
    cfg: BCConfig,
    starts: list[np.ndarray],
) -> tuple[dict, np.ndarray]:
    """Train every cell with the compiled kernel on this process's threads; (parameters by
    name, final loss per cell), as :func:`~pcpg_dist.stages.bc.torch_engine.train_group`."""
    import numba

    from pcpg_dist.stages.bc.kernel import train_kernel

    if cfg.batch_size is not None:  # minibatches are blocks of one fixed shuffle per cell
        data = [
            tuple(a[order] for a in x)
            for x, order in (
                (x, np.random.default_rng([c.spec.seed, 1]).permutation(len(x[2])))
                for c, x in zip(cells, data, strict=True)
            )
        ]
    rows = [len(x[2]) for x in data]
    row_off = np.r_[0, np.cumsum(rows)].astype(np.int64)
    xt = np.concatenate([(s - c.mean) / c.std for c, (s, _, _, _) in zip(cells, data, strict=True)])
    neg = np.concatenate([np.where(v, 0.0, INVALID_LOGIT) for _, v, _, _ in data]).astype(
        np.float32
    )
    acts = np.concatenate([a for _, _, a, _ in data]).astype(np.int64)
    wn = np.concatenate([w / w.sum() for _, _, _, w in data]).astype(np.float32)
    theta = np.stack(starts).astype(np.float32)
    numel = [x for a, b in zip(sizes[:-1], sizes[1:], strict=True) for x in (a * b, b)]
    offs = np.r_[0, np.cumsum(numel)].astype(np.int64)
    # follow the thread count the caller gave torch (parallel.set_threads): an oversubscribed
    # prange on a busy machine waits for its slowest thread
    numba.set_num_threads(max(1, min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS)))
    schedule, sched_off = _thread_schedule(rows, numba.get_num_threads())
    losses = np.zeros(len(cells))
    train_kernel(
        np.ascontiguousarray(xt.T, np.float32),
        np.ascontiguousarray(neg.T),
        acts,
        wn,
        row_off,
        theta,
        np.array(sizes, np.int64),
        offs[0:-1:2].copy(),
        offs[1::2].copy(),
        cfg.epochs,
        cfg.lr,
        cfg.betas[0],
        cfg.betas[1],
        cfg.eps,
        cfg.activation == "relu",
        schedule,
        sched_off,
        losses,
        cfg.batch_size or 0,
    )
    out = {}
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        out[f"W{i}"] = theta[:, offs[2 * i] : offs[2 * i + 1]].reshape(-1, a, b).copy()
        out[f"b{i}"] = theta[:, offs[2 * i + 1] : offs[2 * i + 2]].copy()
    return out, losses
