"""Fine-tuning from the No Clustering agent, and under ``bc.init: auto`` its check: a cell keeps
its fine-tune only where, in a fair trial, fine-tuning predicts held-out steps better.

Why a trial with a No Clustering agent of its own: the No Clustering agent was trained on every
training step. Compared with a fine-tune on held-out steps of a cell, it has seen them (and on a
log whose states rarely repeat, memorised them) while the fine-tune has not: on tictactoe such a
check kept no fine-tune (PCPG 0.430, No Clustering's, against 0.502 fine-tuned; docs/zoo.md). So
the trial fits a No Clustering agent to its rows *without* the held-out steps, fine-tunes that
on each cell's other steps, and scores the two on the held-out steps, which neither has seen.

Half of each cell's steps are held out (``bc.finetune_check: 0.5``): on the five zoo design
games whose verdict doubts, the trial's verdict agreed with the cells' test steps on 20 of 20
cells, with a fifth on 15 of 20 (benchmarks/zoo/finetune_trial_exp.py, docs/bc_and_evaluation.md).
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from pcpg_dist.config.stages import BCConfig
from pcpg_dist.stages.bc.network import layer_sizes
from pcpg_dist.stages.bc.train import train_cells
from pcpg_dist.stages.bc.trained import TrainedCells
from pcpg_dist.stages.cell_rows import dedupe_rows
from pcpg_dist.stages.ranking import Cell

#: Fewest held-out steps with which a cell's fine-tune is checked; a smaller cell keeps its
#: fine-tune unchecked (a handful of steps cannot tell two agents apart).
MIN_CHECK_STEPS = 20

Rows = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # states, valid, actions, weights


def finetune_cells(
    cells: Sequence[Cell],
    cfg: BCConfig,
    init: Sequence[list[np.ndarray]],
    bases: Sequence[Cell] | None = None,
    base_cfg: BCConfig | None = None,
) -> TrainedCells:
    """Fine-tune each cell from ``init[i]`` (the No Clustering agent of its p and seed) with
    ``cfg``. With ``bases`` (``bases[i]``: the No Clustering cell that agent was trained on, with
    ``base_cfg``) and under ``bc.init: auto`` with ``finetune_check`` > 0, a cell whose fair
    trial (:func:`kept_starts`) does not favour its fine-tune *is* its No Clustering agent."""
    kept = kept_starts(cells, cfg, bases, base_cfg or cfg) if bases and checks(cfg) else set()
    keep = sorted(kept)
    tune = [i for i in range(len(cells)) if i not in kept]
    parts = []
    if keep:
        parts.append(starting_cells([cells[i] for i in keep], cfg, [init[i] for i in keep]))
    if tune:
        parts.append(train_cells([cells[i] for i in tune], cfg, [init[i] for i in tune]))
    return TrainedCells.concat(parts).select([c.spec.key for c in cells])


def checks(cfg: BCConfig) -> bool:
    """Whether fine-tunes are checked: under ``bc.init: auto`` with ``finetune_check`` > 0."""
    return cfg.init == "auto" and cfg.finetune_check > 0


def kept_starts(
    cells: Sequence[Cell], cfg: BCConfig, bases: Sequence[Cell], base_cfg: BCConfig
) -> set[int]:
    """The per-cluster cells whose fine-tune does not pay in a fair trial (:func:`trial`;
    corrupted-label cells are the corruption study's and keep their fine-tune): where the
    trial's fine-tune predicts the held-out steps no better (accuracy; at equal accuracy,
    cross-entropy). Stricter rules were read on the zoo's design games and agreed less often
    with the test steps (docs/zoo-notebook.md, "The fine-tune check's margins")."""
    return kept_of(*trial(cells, cfg, bases, base_cfg))


def kept_of(checked, trained_bases, tuned, helds) -> set[int]:
    """:func:`kept_starts`' rule applied to one :func:`trial`'s outcome."""
    keep = set()
    for j, i in enumerate(checked):
        (acc, loss), (acc0, loss0) = scores(tuned, j, helds[j]), scores(trained_bases, j, helds[j])
        if acc < acc0 or (acc == acc0 and loss >= loss0):
            keep.add(i)
    return keep


def trial(
    cells: Sequence[Cell], cfg: BCConfig, bases: Sequence[Cell], base_cfg: BCConfig
) -> tuple[list[int], TrainedCells | None, TrainedCells | None, list[Rows]]:
    """(checked cells, trial No Clustering agents, trial fine-tunes, held-out steps): per
    per-cluster cell, a share ``finetune_check`` of its steps is held out (:func:`split_rows`),
    a trial No Clustering agent fits its No Clustering cell without them (``base_cfg``), and
    the trial fine-tunes that agent on the cell's other steps (``cfg``). The j-th agents of
    both belong to ``checked[j]``. Each cell's trial depends on that cell alone, so a cell
    trains the same in any group."""
    checked, trial_bases, fits, helds = [], [], [], []
    for i, c in enumerate(cells):
        if c.spec.kind != "pcpg":  # corrupted-label agents: the corruption study, unchecked
            continue
        split = split_rows(c, cfg.finetune_check)
        rest = None if split is None else without(bases[i], [split[1]])
        if rest is not None:
            checked.append(i)
            key = f"{rest.spec.key}~{c.spec.key}"  # one trial base per cell, keys unique
            trial_bases.append(replace(rest, spec=replace(rest.spec, key=key)))
            fits.append(split[0])
            helds.append(split[1])
    if not checked:
        return [], None, None, []
    trained_bases = train_cells(trial_bases, base_cfg)
    starts = [trained_bases.cell_params(j) for j in range(len(checked))]
    return checked, trained_bases, train_cells(fits, cfg, starts), helds


def split_rows(cell: Cell, share: float) -> tuple[Cell, Rows] | None:
    """(the cell on its fitted steps, its held-out steps): each distinct row's count is split
    at random (binomially, from the cell's seed and key), a share ``share`` of the steps held
    out, as if the raw steps had been split: a state that recurs (an opening, a start) lands on
    both sides, as it recurs in test episodes. None where fewer than MIN_CHECK_STEPS steps would
    be held out, or none fitted."""
    counts = np.rint(cell.weights).astype(np.int64)
    rng = np.random.default_rng([0xC4EC, cell.spec.seed, zlib.crc32(cell.spec.key.encode())])
    held = rng.binomial(counts, share)
    fit = counts - held
    if held.sum() < MIN_CHECK_STEPS or not fit.any():
        return None

    def rows(w: np.ndarray) -> Rows:
        on = w > 0
        return cell.states[on], cell.valid[on], cell.actions[on], w[on].astype(np.float64)

    states, valid, actions, weights = rows(fit)
    return replace(cell, states=states, valid=valid, actions=actions, weights=weights), rows(held)


def without(base: Cell, held: Sequence[Rows]) -> Cell | None:
    """``base`` less the ``held`` steps (matched to its rows by state, valid mask and action,
    :func:`~pcpg_dist.stages.cell_rows.dedupe_rows`); None where nothing is left."""
    parts = [(base.states, base.valid, base.actions, base.weights), *held]
    states, valid, actions, _, inverse = dedupe_rows(
        *(np.concatenate([part[j] for part in parts]) for j in range(3)),
        return_inverse=True,
    )
    n = len(base.actions)
    weights = np.concatenate([part[3] for part in parts]).astype(np.float64)
    left = np.bincount(inverse[:n], weights[:n], len(actions))
    left -= np.bincount(inverse[n:], weights[n:], len(actions))
    on = left > 0
    if not on.any():
        return None
    return replace(base, states=states[on], valid=valid[on], actions=actions[on], weights=left[on])


def starting_cells(
    cells: Sequence[Cell], cfg: BCConfig, init: Sequence[list[np.ndarray]]
) -> TrainedCells:
    """The cells' starting parameters as an ensemble, each cell's loss its start's on its rows."""
    sizes = layer_sizes(cells[0].state_dim, cells[0].n_actions, cfg)
    names = [f"{w}{layer}" for layer in range(len(sizes) - 1) for w in "Wb"]
    params = {
        name: np.stack([np.asarray(p[j], np.float32) for p in init]) for j, name in enumerate(names)
    }
    start = TrainedCells.of_cells(cells, sizes, cfg.activation, params, np.zeros(len(cells)))
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


def bases_of(cells: Sequence[Cell], candidates: Sequence[Cell]) -> list[Cell]:
    """Each cell's No Clustering cell among ``candidates`` (the one of its p and seed)."""
    table = {(c.spec.p, c.spec.seed): c for c in candidates if c.spec.kind == "nc"}
    return [table[(c.spec.p, c.spec.seed)] for c in cells]
