"""Training a group of cells: checks, deduplication, starting points, and the engine's dispatch.

Why here and not in an engine: both engines take the same prepared rows and starting vectors and
must answer the same way (one TrainedCells, divergence refused), so that shared part is one
function whatever engine runs.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from pcpg_dist.common.errors import DataError, TrainingError
from pcpg_dist.config.stages import BCConfig
from pcpg_dist.stages.bc.device import bc_device, choose_engine
from pcpg_dist.stages.bc.network import layer_sizes, start_vector
from pcpg_dist.stages.bc.numba_engine import train_numba
from pcpg_dist.stages.bc.torch_engine import buckets, train_group
from pcpg_dist.stages.bc.trained import TrainedCells
from pcpg_dist.stages.cell_rows import dedupe_rows
from pcpg_dist.stages.ranking import Cell


def train_cells(
    cells: Sequence[Cell], cfg: BCConfig, init: Sequence[list[np.ndarray] | None] | None = None
) -> TrainedCells:
    """Train one policy per cell; pure and deterministic (what one Ray task runs on a group).

    ``init[i]``, where given, is cell i's starting parameters (W0, b0, W1, b1, ...; e.g. a
    trained No Clustering agent to fine-tune) instead of the seeded initialisation.
    """
    _check_group(cells)
    d, n_actions = cells[0].state_dim, cells[0].n_actions
    data = [
        dedupe_rows(c.states, c.valid, c.actions, c.weights)
        if cfg.dedupe
        else (c.states, c.valid, c.actions, c.weights)
        for c in cells
    ]
    sizes = layer_sizes(d, n_actions, cfg)
    if init is not None and len(init) != len(cells):
        raise DataError(
            f"{len(init)} starting parameter sets for {len(cells)} cells: give one per cell (None: seeded)"
        )
    starts = [
        start_vector(sizes, c, None if init is None else init[i]) for i, c in enumerate(cells)
    ]
    device = bc_device(cfg)
    if choose_engine(cfg, device) == "numba":
        params, losses, _ = train_numba(cells, data, sizes, cfg, starts)
    else:
        params, losses = _train_buckets(cells, data, sizes, cfg, device, starts)
    check_finite(cells, params, losses, cfg)
    return TrainedCells.of_cells(cells, sizes, cfg.activation, params, losses)


def _check_group(cells: Sequence[Cell]) -> None:
    """A DataError unless the cells can share one call: some cells, one state width and action
    count, distinct keys."""
    if not cells:
        raise DataError("no cells to train")
    d, n_actions = cells[0].state_dim, cells[0].n_actions
    for c in cells:
        if c.state_dim != d or c.n_actions != n_actions:
            raise DataError(
                f"cell {c.key} has state width {c.state_dim} and {c.n_actions} actions; "
                f"cell {cells[0].key} has {d} and {n_actions}: train them separately"
            )
    if len({c.key for c in cells}) != len(cells):
        raise DataError("cell keys must be unique")


def _train_buckets(
    cells: Sequence[Cell],
    data: list[tuple[np.ndarray, ...]],
    sizes: tuple[int, ...],
    cfg: BCConfig,
    device: torch.device,
    starts: list[np.ndarray],
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The torch engine over buckets of similar row counts; (parameters by name, loss per cell)."""
    dtype = torch.float32 if cfg.dtype == "float32" else torch.float64
    params = {
        f"{w}{i}": np.zeros((len(cells), *((a, b) if w == "W" else (b,))), np.float32)
        for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True))
        for w in "Wb"
    }
    losses = np.zeros(len(cells))
    for group in buckets([len(x[2]) for x in data], cfg.bucket_overhead_rows):
        trained, loss = train_group(
            [cells[i] for i in group],
            [data[i] for i in group],
            sizes,
            cfg,
            device,
            dtype,
            [starts[i] for i in group],
        )
        for name, value in trained.items():
            params[name][group] = value
        losses[group] = loss
    return params, losses


def check_finite(
    cells: Sequence[Cell], params: dict[str, np.ndarray], losses: np.ndarray, cfg: BCConfig
) -> None:
    """Diverged training (NaN or infinite weights or loss) stops the run: such a policy must never
    be evaluated, cached or published as an agent."""
    bad = ~np.isfinite(np.asarray(losses, np.float64))
    for value in params.values():
        bad |= ~np.isfinite(value.reshape(len(cells), -1)).all(axis=1)
    if bad.any():
        first = int(np.argmax(bad))
        raise TrainingError(
            f"BC training diverged for {int(bad.sum())} of {len(cells)} cells (first: "
            f"{cells[first].key}): non-finite weights or loss with bc.lr={cfg.lr}, "
            f"bc.betas={list(cfg.betas)}, bc.eps={cfg.eps}, bc.dtype={cfg.dtype}; lower bc.lr "
            f"or check the data's state features for huge values"
        )
