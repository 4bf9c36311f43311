"""``bc.init``: training a unit's cells in one or two rounds (from scratch, or fine-tuned from
the No Clustering agent of the same p and seed).

Why apart from :mod:`~pcpg_dist.stages.bc.train`: the runner runs the two rounds as separate
Ray tasks and needs the split, the starting parameters and the fine-tuning settings on their own.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import replace
from typing import TypeVar

import numpy as np

from pcpg_dist.common.errors import DataError
from pcpg_dist.config.stages import BCConfig
from pcpg_dist.stages.bc.network import layer_sizes
from pcpg_dist.stages.bc.train import train_cells
from pcpg_dist.stages.bc.trained import TrainedCells
from pcpg_dist.stages.ranking import Cell, CellSpec

C = TypeVar("C", Cell, CellSpec)


def _spec(cell: Cell | CellSpec) -> CellSpec:
    return cell.spec if isinstance(cell, Cell) else cell


#: Adam steps of a fine-tuned cell under ``bc.init: auto`` (finetune_epochs unset). Measured on
#: the zoo (docs/zoo.md): a short fine-tune keeps what the No Clustering agent knows; a full
#: one (2000 steps) forgot it (minigrid_fourrooms 0.735 either way, against No Clustering 0.754)
AUTO_FINETUNE_EPOCHS = 100


def resolve_init(cfg: BCConfig, doubted: bool = False) -> str:
    """``scratch`` or ``no_clustering``. ``auto`` is no_clustering where the unit's clustering
    verdict doubts its styles (``Verdict.doubts_styles``: weak or no evidence), else scratch
    (the paper): styles found, or no confidence measured."""
    if cfg.init != "auto":
        return cfg.init
    return "no_clustering" if doubted else "scratch"


def split_for_init(
    cells: Sequence[C], cfg: BCConfig, doubted: bool = False
) -> tuple[list[C], list[C]]:
    """(cells that start from their seeded init, cells that start from a No Clustering agent):
    where ``bc.init`` resolves to no_clustering (:func:`resolve_init`) the No Clustering cells
    train first, the others after. Cells or their specs (a runner plans groups from specs)."""
    if resolve_init(cfg, doubted) == "scratch":
        return list(cells), []
    nc = [c for c in cells if _spec(c).kind == "nc"]
    return nc, [c for c in cells if _spec(c).kind != "nc"]


def init_from(cells: Sequence[Cell | CellSpec], base: TrainedCells) -> list[list[np.ndarray]]:
    """Each cell's starting parameters: the No Clustering agent in ``base`` of its p and seed."""
    table = {(s.p, s.seed): i for i, s in enumerate(base.specs) if s.kind == "nc"}
    specs = [_spec(c) for c in cells]
    missing = [s.key for s in specs if (s.p, s.seed) not in table]
    if missing:
        raise DataError(
            f"bc.init no_clustering: cell {missing[0]} has no No Clustering agent of "
            "its p and seed to start from"
        )
    return [base.cell_params(table[(s.p, s.seed)]) for s in specs]


def finetune_config(cfg: BCConfig) -> BCConfig:
    """The settings of the cells that start from No Clustering: ``finetune_epochs`` epochs, or
    when unset ``epochs`` (init no_clustering) or at most AUTO_FINETUNE_EPOCHS (init auto)."""
    if cfg.finetune_epochs is not None:
        epochs = cfg.finetune_epochs
    elif cfg.init == "auto":
        epochs = min(cfg.epochs, AUTO_FINETUNE_EPOCHS)
    else:
        return cfg
    return cfg.model_copy(update={"epochs": epochs})


def train_plan(cells: Sequence[Cell], cfg: BCConfig, doubted: bool = False) -> TrainedCells:
    """Train a unit's planned cells in this process, honouring ``bc.init`` (``doubted``: whether
    the unit's clustering verdict doubts its styles, for auto; the runner does the same as two
    rounds of Ray tasks)."""
    first, rest = split_for_init(cells, cfg, doubted)
    base = train_cells(first, cfg)
    if not rest:
        return base
    tuned = finetune_cells(rest, finetune_config(cfg), init_from(rest, base))
    return TrainedCells.concat([base, tuned]).select([c.key for c in cells])


#: Fewest held-out rows with which a cell's fine-tune is checked; a smaller cell keeps its
#: fine-tune unchecked (a handful of rows cannot tell two agents apart).
MIN_CHECK_ROWS = 10

Rows = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # states, valid, actions, weights


def finetune_cells(
    cells: Sequence[Cell], cfg: BCConfig, init: Sequence[list[np.ndarray]]
) -> TrainedCells:
    """Fine-tune each cell from its start (``init``: the No Clustering agents). Under ``bc.init:
    auto`` a fine-tune is kept only where it helps: a share ``finetune_check`` of each cell's
    rows is held out (drawn from the cell's seed and key), a trial fine-tune fits the rest, and a
    cell whose trial does not predict the held-out rows better than its start (weighted accuracy;
    at equal accuracy, cross-entropy) *is* its start. The other cells fine-tune on all their rows, as without the check."""
    checked = []
    if cfg.init == "auto" and cfg.finetune_check > 0:
        for i, c in enumerate(cells):
            split = split_rows(c, cfg.finetune_check)
            if split is not None:
                checked.append((i, *split))
    start = starting_cells(cells, cfg, init)
    keep: set[int] = set()
    if checked:
        trial = train_cells([fit for _, fit, _ in checked], cfg, [init[i] for i, _, _ in checked])
        for j, (i, _, held) in enumerate(checked):
            (acc, loss), (acc0, loss0) = scores(trial, j, held), scores(start, i, held)
            if acc < acc0 or (acc == acc0 and loss >= loss0):
                keep.add(i)
    parts = [start.select([cells[i].spec.key for i in sorted(keep)])] if keep else []
    tune = [i for i in range(len(cells)) if i not in keep]
    if tune:
        parts.append(train_cells([cells[i] for i in tune], cfg, [init[i] for i in tune]))
    return TrainedCells.concat(parts).select([c.spec.key for c in cells])


def split_rows(cell: Cell, share: float) -> tuple[Cell, Rows] | None:
    """(the cell on its fitted rows, its held-out rows), a share ``share`` held out at random from
    the cell's seed and key; None where fewer than MIN_CHECK_ROWS rows would be held out."""
    n = len(cell.actions)
    held = int(round(share * n))
    if held < MIN_CHECK_ROWS or held >= n:
        return None
    rng = np.random.default_rng([0xC4EC, cell.spec.seed, zlib.crc32(cell.spec.key.encode())])
    order = rng.permutation(n)
    fit, out = np.sort(order[held:]), np.sort(order[:held])

    def rows(idx: np.ndarray) -> Rows:
        return cell.states[idx], cell.valid[idx], cell.actions[idx], cell.weights[idx]

    states, valid, actions, weights = rows(fit)
    kept = replace(cell, states=states, valid=valid, actions=actions, weights=weights)
    return kept, rows(out)


def starting_cells(
    cells: Sequence[Cell], cfg: BCConfig, init: Sequence[list[np.ndarray]]
) -> TrainedCells:
    """The cells' starting parameters as an ensemble, each cell's loss its start's on its rows."""
    sizes = layer_sizes(cells[0].state_dim, cells[0].n_actions, cfg)
    names = [f"{w}{layer}" for layer in range(len(sizes) - 1) for w in "Wb"]
    params = {
        name: np.stack([np.asarray(p[j], np.float32) for p in init]) for j, name in enumerate(names)
    }
    start = TrainedCells(
        tuple(c.spec for c in cells),
        sizes,
        cfg.activation,
        params,
        np.stack([c.mean for c in cells]),
        np.stack([c.std for c in cells]),
        np.zeros(len(cells)),
    )
    losses = [
        scores(start, i, (c.states, c.valid, c.actions, c.weights))[1] for i, c in enumerate(cells)
    ]
    return replace(start, final_loss=np.asarray(losses))


def scores(trained: TrainedCells, cell: int, rows: Rows) -> tuple[float, float]:
    """(weighted accuracy of the greedy valid action, weighted mean cross-entropy in nats) of one
    cell of ``trained`` on ``rows``."""
    states, valid, actions, weights = rows
    lg = trained.logits(states, cell, valid).astype(np.float64)
    top = lg.max(axis=1, keepdims=True)
    log_z = top[:, 0] + np.log(np.exp(lg - top).sum(axis=1))
    picked = lg[np.arange(len(actions)), actions]
    w = weights / weights.sum()
    hit = np.argmax(lg, axis=1) == actions
    return float(w @ hit), float(w @ (log_z - picked))
