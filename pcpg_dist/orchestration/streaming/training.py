"""Step C and the evaluation over blocks: the BC cells in as few tasks as use every CPU (a few
torch threads each), each streaming the materialised training rows once an epoch, and the
held-out rows' accuracy counts."""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass

import numpy as np
import psutil

from pcpg_dist.domains.base import StreamSource
from pcpg_dist.orchestration.streaming.engine import quiet_engine
from pcpg_dist.stages.streamed import cells as P


@dataclass(frozen=True)
class TrainSpec:
    """How every BC cell trains on the stream: the bc section's network and Adam settings, and
    the epoch budget with early stopping."""

    d: int
    n_actions: int
    layers: int
    width: int
    activation: str
    lr: float
    betas: tuple[float, float]
    eps: float
    batch: int
    max_epochs: int
    patience: int = 1
    tol: float = 1e-3


MAX_BC_THREADS = 4  # torch threads of one BC task: past a few, a small MLP's batches gain little


def bc_tasks(node_cpus: list[int], n_cells: int) -> tuple[int, int]:
    """(tasks, torch threads each) for ``n_cells`` BC cells on nodes of ``node_cpus`` CPUs: as
    few tasks as keep every CPU busy, since each task imports torch once (~0.5 GB) and streams
    every training row once an epoch; threads at most :data:`MAX_BC_THREADS` and no more than
    the smallest node has, so that every task fits on any node; at most one task per cell."""
    usable = [c for c in node_cpus if c >= 1] or [1]
    threads = max(1, min(MAX_BC_THREADS, min(usable)))
    return max(1, min(n_cells, sum(c // threads for c in usable))), threads


def train_group(
    rows,
    held_out,
    cells: list[tuple[int, int]],
    spec: TrainSpec,
    seed: int,
    k: int,
    threads: int = 1,
) -> dict:
    """Train ``cells`` (cluster or NC, p index) together over the streamed rows, epoch by epoch,
    until every cell's validation loss stops improving, then count their correct predictions on
    the ``held_out`` rows (here, where torch is already loaded: no other worker imports it).
    Runs in a Ray task of ``threads`` CPUs."""
    import os
    import time

    import ray
    import torch

    from pcpg_dist.common.devices import set_threads
    from pcpg_dist.stages.streamed import policy

    set_threads(threads)
    quiet_engine()
    model = policy.StackedPolicy(
        len(cells), spec.d, spec.n_actions, spec.layers, spec.width, spec.activation, seed
    )
    opt = torch.optim.Adam(model.parameters(), lr=spec.lr, betas=spec.betas, eps=spec.eps)
    stop = policy.EarlyStop(len(cells), tol=spec.tol, patience=spec.patience)
    epochs = 0
    for epoch in range(spec.max_epochs):
        val_sum, val_n = np.zeros(len(cells)), np.zeros(len(cells))
        for batch in rows.iter_batches(batch_size=spec.batch, batch_format="numpy"):
            member = P.membership(batch["code"], cells)
            held = (batch["code"] & P.VALIDATION) != 0
            x = torch.as_tensor(batch["x"])
            y = torch.as_tensor(batch["y"].astype(np.int64))
            logits = model(x)
            if held.any():
                with torch.no_grad():
                    mh = torch.as_tensor(member & held[None, :], dtype=torch.float32)
                    val_sum += policy.cell_losses(logits.detach(), y, mh).numpy()
                    val_n += mh.sum(1).numpy()
            mt = member & ~held[None, :]
            counts = mt.sum(1)
            if not counts.any():
                continue
            weight = torch.as_tensor(mt / np.maximum(counts, 1)[:, None], dtype=torch.float32)
            loss = policy.cell_losses(logits, y, weight).sum()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        epochs = epoch + 1
        stop.update(np.where(val_n > 0, val_sum / np.maximum(val_n, 1), 0.0), model)
        if stop.all_done:
            break
    states = [s if s is not None else model.cell_state(i) for i, s in enumerate(stop.best_states)]
    t0 = time.perf_counter()
    model.load_cells(states)
    counts = np.zeros(len(cells) * k + k)
    for batch in held_out.iter_batches(batch_size=spec.batch, batch_format="numpy"):
        cluster = P.cluster_of(batch["code"])
        counts += policy.accuracy_counts(model, batch["x"], batch["y"].astype(np.int64), cluster, k)
    return {
        "cells": cells,
        "states": states,
        "epochs": epochs,
        "val_loss": stop.best.tolist(),
        "correct": counts[: len(cells) * k].reshape(len(cells), k),
        "test_rows": counts[len(cells) * k :],
        "evaluate_s": time.perf_counter() - t0,
        "worker": (ray.get_runtime_context().get_node_id(), os.getpid()),
    }


def train_cells(
    rows, held_out, cells, spec: TrainSpec, seed: int, k: int, node_cpus: list[int]
) -> list[dict]:
    """The cells split round-robin into :func:`bc_tasks` groups, each a Ray task that trains its
    cells and counts their correct predictions on the ``held_out`` rows."""
    import ray

    tasks, threads = bc_tasks(node_cpus, len(cells))
    # max_calls=1: the worker exits with its task, so the memory it held goes back at once
    task = ray.remote(num_cpus=threads, max_retries=2, max_calls=1)(train_group)
    groups = [cells[g::tasks] for g in range(tasks)]
    results = ray.get(
        [
            task.remote(rows, held_out, group, spec, seed * 7919 + g, k, threads)
            for g, group in enumerate(groups)
        ]
    )
    _until_exited([r["worker"] for r in results])
    return results


def _until_exited(workers: list[tuple[str, int]], timeout: float = 60.0) -> None:
    """Wait, at most ``timeout`` seconds, for the BC tasks' workers on this node to exit. Each
    exits after its task (``max_calls=1``) but holds torch and its buffers (~1 GB) a second or
    two longer, while the next step already starts workers of its own: measured, that overlap
    was a million-trajectory run's peak memory. On a loaded machine the exit took over 10 s (CI,
    2026-11-30); a worker that is a zombie has given its memory back and counts as gone."""
    import ray

    here = ray.get_runtime_context().get_node_id()
    procs = []
    for node, pid in workers:
        if node == here:
            with contextlib.suppress(psutil.NoSuchProcess):
                procs.append(psutil.Process(pid))
    deadline = time.monotonic() + timeout
    while (procs := [p for p in procs if _running(p)]) and time.monotonic() < deadline:
        time.sleep(0.05)


def _running(proc: psutil.Process) -> bool:
    try:
        return proc.is_running() and proc.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def train_spec(cfg, source: StreamSource) -> TrainSpec:
    b = cfg.bc
    return TrainSpec(
        d=len(source.states),
        n_actions=source.n_actions,
        layers=b.hidden_layers,
        width=b.hidden_size,
        activation=b.activation,
        lr=b.lr,
        betas=tuple(b.betas),
        eps=b.eps,
        # about 256 steps an epoch on a small log, at most 16,384 rows a step on a large one
        batch=b.batch_size
        if isinstance(b.batch_size, int)
        else int(np.clip(source.steps // 256, 1024, 16384)),
        max_epochs=min(b.epochs, source.max_epochs),
    )
