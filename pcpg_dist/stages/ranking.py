"""Step B: score trajectories by skill, split them, and keep the top p of every cluster.

Why a separate module: the runner plans training cells from these index sets and the evaluation
re-derives the *same* test subsets H_{k,p}^test from them, so both must call one deterministic
implementation (ties broken by trajectory id, ``ceil`` so no subset is ever emptied by p).

The split is made at trajectory level *before* thresholding, so every model is tested on
trajectories it never saw, and the test subsets are thresholded exactly like the training ones
(the paper's Table 4 evaluates pi_{k,p} on H_{k',p}).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass

import numpy as np

from pcpg_dist.common.errors import DataError
from pcpg_dist.config.stages import RankConfig
from pcpg_dist.dataset import Dataset
from pcpg_dist.domains.base import ScoreFn

# the default split and skill score belong to the domain API (a domain's units() and score() fall
# back on them); Step B and its many callers keep reaching them here
from pcpg_dist.domains.defaults import score_dataset
from pcpg_dist.stages.cell_rows import SubsetRows


def n_kept(n: int, p: float) -> int:
    """How many of ``n`` trajectories the top-p keeps: ``ceil(p n)``, at least 1 when n > 0."""
    if n == 0:
        return 0
    # the small epsilon keeps e.g. 0.1 * 30 = 3.0000000000000004 from rounding up to 4
    return max(1, min(n, math.ceil(p * n - 1e-9)))


def top_p(
    indices: np.ndarray,
    scores: np.ndarray,
    p: float,
    ids: np.ndarray,
    last: np.ndarray | None = None,
) -> np.ndarray:
    """The top ``p`` fraction of ``indices`` by ``scores[indices]``, ties broken by smaller id.

    ``scores``, ``ids`` and ``last`` are indexed by trajectory position (0..n-1); trajectories
    where ``last`` is true rank after all others (:func:`ranked_last`). Returns the kept
    positions, sorted ascending, so downstream arrays do not depend on the ranking order.
    """
    indices = np.asarray(indices, dtype=np.int64)
    if not 0.0 < p <= 1.0:
        raise DataError(f"p must lie in (0, 1], got {p}")
    if indices.size == 0:
        return indices
    keys = (ids[indices], -scores[indices]) + (() if last is None else (last[indices],))
    order = np.lexsort(keys)  # last key is primary
    return np.sort(indices[order[: n_kept(len(indices), p)]])


def _no_margins(dataset: Dataset) -> str:
    return (
        f"ranking.style_margin: the clustering of {dataset.domain}-{dataset.env} gives no likelihood "
        "margins (its method falls back to one without a likelihood on continuous states): use "
        "clustering.method policy_mix, or set ranking.style_margin to 0"
    )


def check_margins_come(cfg, datasets: Sequence[Dataset]) -> None:
    """Before Step A: a DataError if ``ranking.style_margin`` will find a clustering without
    margins (``bag_auto`` on continuous states), rather than after every unit was clustered."""
    from pcpg_dist.config.clusterers import CLUSTERERS
    from pcpg_dist.stages.clustering import falls_back
    from pcpg_dist.stages.clustering.auto import fallback_for

    method = cfg.clustering.method
    if cfg.ranking.style_margin > 0 and CLUSTERERS[method].continuous_fallback:
        for d in datasets:
            if falls_back(d) and not CLUSTERERS[fallback_for(method, d)].likelihood:
                raise DataError(_no_margins(d))


def ranked_last(margins: np.ndarray | None, cfg: RankConfig, dataset: Dataset) -> np.ndarray | None:
    """The style-aware part of Step B (``ranking.style_margin``; None = the paper's ranking): which
    trajectories rank after the rest of their cluster because their cluster is less than
    ``style_margin`` nats more likely than the next best (``margins`` from the clustering)."""
    if cfg.style_margin <= 0:
        return None
    if margins is None:
        raise DataError(_no_margins(dataset))
    margins = np.asarray(margins, dtype=np.float64)
    if margins.shape != (dataset.n_trajectories,):
        raise DataError(
            f"style margins must have shape ({dataset.n_trajectories},), got {margins.shape}"
        )
    return margins < cfg.style_margin


def threshold(
    labels: np.ndarray,
    indices: np.ndarray,
    scores: np.ndarray,
    ids: np.ndarray,
    ps: Sequence[float],
    k: int | None = None,
    last: np.ndarray | None = None,
) -> dict[tuple[int, float], np.ndarray]:
    """H_{k,p}: for every cluster label k (0..k-1) and p, the top p of ``indices`` with that label
    (``last``: see :func:`top_p`)."""
    labels = np.asarray(labels, dtype=np.int64)
    k = int(labels.max()) + 1 if k is None else k
    out = {}
    for c in range(k):
        members = indices[labels[indices] == c]
        for p in ps:
            out[(c, float(p))] = top_p(members, scores, p, ids, last)
    return out


def threshold_all(
    indices: np.ndarray, scores: np.ndarray, ids: np.ndarray, ps: Sequence[float]
) -> dict[float, np.ndarray]:
    """The No Clustering baseline's subsets: the top p of all of ``indices``."""
    return {float(p): top_p(indices, scores, p, ids) for p in ps}


def corrupt_labels(
    labels: np.ndarray, c: float, k: int, rng: np.random.Generator, mode: str = "wrong"
) -> np.ndarray:
    """Replace exactly ``round(c n)`` labels by a *different* label drawn uniformly
    (``mode="wrong"``), or by a label drawn uniformly among all k (``mode="random"``).

    c = 0 leaves the clustering perfect; c = 1 makes every label wrong (or random).
    """
    labels = np.asarray(labels, dtype=np.int64)
    if not 0.0 <= c <= 1.0:
        raise DataError(f"corruption level must lie in [0, 1], got {c}")
    if k < 2 and c > 0:
        raise DataError("cannot corrupt labels with fewer than 2 clusters")
    out = labels.copy()
    n_bad = int(round(c * len(labels)))
    which = rng.permutation(len(labels))[:n_bad]
    # a shift of 1..k-1 modulo k is a uniform draw among the k-1 other labels
    if mode == "random":
        out[which] = rng.integers(0, k, size=n_bad)
    else:
        out[which] = (labels[which] + rng.integers(1, k, size=n_bad)) % k
    return out


def corruption_rng(base_seed: int, seed: int, c: float) -> np.random.Generator:
    """The generator of the corruption draw for one (model seed, level): planning and
    evaluation both call this, so they see the same corrupted labels."""
    return np.random.default_rng([base_seed, seed, int(round(c * 1_000_000))])


# ----------------------------------------------------------------------- training cells
@dataclass(frozen=True)
class CellSpec:
    """What a cell is, without its data: enough for evaluation to find it again.

    ``kind`` is "pcpg" (one cluster k), "nc" (No Clustering: top p of everything) or "corrupt"
    (cluster k of labels corrupted at level c). ``k`` is -1 and ``c`` is 0.0 where they do not apply.
    """

    key: str
    kind: str
    k: int
    p: float
    seed: int
    c: float = 0.0


@dataclass(frozen=True, eq=False)
class Cell:
    """One behavioural-cloning problem: distinct (state, valid mask, action) rows with counts.

    ``mean``/``std`` normalise the inputs; they are fitted on the environment's training rows
    (not on the cell) so that a cell with a constant feature (a small p) still gets a sane scale
    and every model of an environment sees its inputs on one scale.
    """

    spec: CellSpec
    states: np.ndarray  # (n, d) float32
    valid: np.ndarray  # (n, A) bool
    actions: np.ndarray  # (n,) int64
    weights: np.ndarray  # (n,) float64: how many raw steps each row stands for
    mean: np.ndarray  # (d,) float32
    std: np.ndarray  # (d,) float32
    n_trajectories: int = 0

    def __post_init__(self) -> None:
        n, key = len(self.actions), self.spec.key
        if n == 0:
            raise DataError(
                f"cell {key}: no training steps (the subset H is empty); check the clustering and p"
            )
        if self.states.ndim != 2 or self.states.shape[0] != n:
            raise DataError(f"cell {key}: states must have shape ({n}, d), got {self.states.shape}")
        if self.valid.ndim != 2 or self.valid.shape[0] != n or self.valid.dtype != bool:
            raise DataError(
                f"cell {key}: valid must have shape ({n}, n_actions), got {self.valid.shape} {self.valid.dtype}"
            )
        if self.weights.shape != (n,) or (self.weights <= 0).any():
            raise DataError(f"cell {key}: weights must be {n} positive counts")
        d = self.states.shape[1]
        if self.mean.shape != (d,) or self.std.shape != (d,) or (self.std <= 0).any():
            raise DataError(f"cell {key}: mean/std must have shape ({d},) with std > 0")
        if (self.actions < 0).any() or (self.actions >= self.valid.shape[1]).any():
            raise DataError(f"cell {key}: actions must lie in 0..{self.valid.shape[1] - 1}")
        if not self.valid[np.arange(n), self.actions].all():
            row = int(np.nonzero(~self.valid[np.arange(n), self.actions])[0][0])
            raise DataError(
                f"cell {key}: row {row} takes action {int(self.actions[row])}, "
                f"which its valid mask forbids"
            )

    @property
    def key(self) -> str:
        return self.spec.key

    @property
    def n_rows(self) -> int:
        return len(self.actions)

    @property
    def state_dim(self) -> int:
        return int(self.states.shape[1])

    @property
    def n_actions(self) -> int:
        return int(self.valid.shape[1])


def fmt(x: float) -> str:
    """Short, stable text of a p or c in keys and metric names: 1, 0.75, 0.1."""
    return f"{x:g}"


def _checked_labels(dataset: Dataset, labels: np.ndarray) -> np.ndarray:
    """One cluster index >= 0 per trajectory, as int64."""
    labels = np.asarray(labels, dtype=np.int64)
    if labels.shape != (dataset.n_trajectories,):
        raise DataError(f"labels must have shape ({dataset.n_trajectories},), got {labels.shape}")
    if (labels < 0).any():
        raise DataError("labels must be cluster indices >= 0 (got a negative label)")
    return labels


def _input_scale(dataset: Dataset, train_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and std (1 where a feature is constant) of the environment's training steps: every
    model of an environment sees its inputs on this one scale."""
    row_traj = dataset.row_trajectory
    steps = dataset.step_rows
    in_train = np.zeros(dataset.n_trajectories, bool)
    in_train[train_idx] = True
    train_rows = steps[in_train[row_traj[steps]]]
    if not len(train_rows):
        raise DataError(f"dataset {dataset.domain}-{dataset.env}: no training steps")
    mean = dataset.states[train_rows].mean(axis=0).astype(np.float32)
    std = dataset.states[train_rows].std(axis=0).astype(np.float32)
    std = np.where(std > 1e-6, std, 1.0).astype(np.float32)
    return mean, std


def plan_cells(
    dataset: Dataset,
    labels: np.ndarray,
    train_idx: np.ndarray,
    cfg: RankConfig,
    seeds: Sequence[int],
    *,
    dedupe: bool = True,
    only: Collection[str] | None = None,
    **subsets_args,
) -> list[Cell]:
    """Every training cell of one environment: PCPG (k, p, seed), No Clustering (p, seed), and
    with ``corruption_levels`` the corrupted-label cells (c, k, p, seed); with ``only``, just the
    cells of those keys (each the same as in the whole plan), in the plan's order. The other
    keyword arguments (``k``, ``score``, ``baseline``, ``corruption_levels``, ``corruption_ps``,
    ``prefix``, ``margins``) are :func:`cell_subsets`'s.

    ``labels`` gives a cluster 0..k-1 per trajectory (e.g. ``dataset.styles``); only the
    trajectories at ``train_idx`` are used. Seeds change the models' initialisation (and the
    corruption draw), never the data split. ``margins``: the clustering's, for
    ``cfg.style_margin`` (:func:`ranked_last`; it applies to PCPG and corrupted cells, whose c = 0
    is PCPG, not to No Clustering, which has no clusters).
    """
    subsets = cell_subsets(dataset, labels, train_idx, cfg, seeds, **subsets_args)
    if only is not None:
        wanted = set(only)
        subsets = [(spec, idx) for spec, idx in subsets if spec.key in wanted]
        missing = wanted - {spec.key for spec, _ in subsets}
        if missing:
            raise DataError(
                f"dataset {dataset.domain}-{dataset.env}: no cell {sorted(missing)[0]} in its plan"
            )
    mean, std = _input_scale(dataset, np.asarray(train_idx, dtype=np.int64))
    rows_of = SubsetRows(dataset, dedupe)
    return [
        Cell(spec, *rows_of(idx, spec.key), mean, std, n_trajectories=len(idx))
        for spec, idx in subsets
    ]


def cell_subsets(
    dataset: Dataset,
    labels: np.ndarray,
    train_idx: np.ndarray,
    cfg: RankConfig,
    seeds: Sequence[int],
    *,
    k: int | None = None,
    score: ScoreFn | None = None,
    baseline: bool = True,
    corruption_levels: Sequence[float] = (),
    corruption_ps: Sequence[float] = (1.0,),
    prefix: str = "",
    margins: np.ndarray | None = None,
) -> list[tuple[CellSpec, np.ndarray]]:
    """Step B without the rows: every cell's spec and its training trajectories (indices), in
    the order :func:`plan_cells` builds them (arguments as there). Cheap: scores and
    thresholds only; a runner plans groups from these and each task builds its own cells."""
    labels = _checked_labels(dataset, labels)
    k = int(labels.max()) + 1 if k is None else int(k)
    train_idx = np.asarray(train_idx, dtype=np.int64)
    scores = score_dataset(dataset, cfg, score)
    last = ranked_last(margins, cfg, dataset)
    ids = dataset.trajectory_ids
    out: list[tuple[CellSpec, np.ndarray]] = []
    subsets = threshold(labels, train_idx, scores, ids, cfg.ps, k, last)
    # A cluster with no training trajectory (k above the number of styles, a tiny split) gets no
    # agent; the evaluation scores its test trajectories with No Clustering's agent of that p.
    for seed in seeds:
        for (c, p), idx in subsets.items():
            if idx.size:
                out.append((CellSpec(f"{prefix}k{c}-p{fmt(p)}-s{seed}", "pcpg", c, p, seed), idx))
        if baseline:
            for p, idx in threshold_all(train_idx, scores, ids, cfg.ps).items():
                out.append((CellSpec(f"{prefix}nc-p{fmt(p)}-s{seed}", "nc", -1, p, seed), idx))
        for level in corruption_levels:
            bad = corrupt_labels(
                labels,
                level,
                k,
                corruption_rng(cfg.corruption_seed, seed, level),
                cfg.corruption_mode,
            )
            for (c, p), idx in threshold(
                bad, train_idx, scores, ids, corruption_ps, k, last
            ).items():
                key = f"{prefix}corrupt{fmt(level)}-k{c}-p{fmt(p)}-s{seed}"
                if idx.size:
                    out.append((CellSpec(key, "corrupt", c, p, seed, float(level)), idx))
    return out
