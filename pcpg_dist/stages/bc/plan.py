"""``bc.init``: training a unit's cells in one or two rounds (from scratch, or fine-tuned from
the No Clustering agent of the same p and seed).

Why apart from :mod:`~pcpg_dist.stages.bc.train`: the runner runs the two rounds as separate
Ray tasks and needs the split, the starting parameters and the fine-tuning settings on their own,
in its driver, without torch or an engine.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

import numpy as np

from pcpg_dist.common.errors import DataError
from pcpg_dist.config.stages import BCConfig
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
    # here, not at the top: the runner's driver plans with this module and never trains
    from pcpg_dist.stages.bc.finetune import bases_of, finetune_cells
    from pcpg_dist.stages.bc.train import train_cells

    first, rest = split_for_init(cells, cfg, doubted)
    base = train_cells(first, cfg)
    if not rest:
        return base
    tuned = finetune_cells(
        rest, finetune_config(cfg), init_from(rest, base), bases_of(rest, first), cfg
    )
    return TrainedCells.concat([base, tuned]).select([c.key for c in cells])
