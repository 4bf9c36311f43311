"""Data for every domain, and how each domain's data becomes evaluation units.

- GridWorld: PBTG, one Ray task per (layout, reward function); one unit per layout, with a seeded
  80/20 trajectory split.
- MiniDungeons: the six proxies, one Ray task per (level, proxy); one unit over all levels whose
  test set is the held-out levels (the paper trains and tests on different levels).
- Mario: the human play log; one unit with a seeded episode split, whose valid actions are the
  event ids seen in the training episodes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pcpg_dist.config import ExperimentConfig
from pcpg_dist.dataset import Dataset, write_datasets
from pcpg_dist.domains.gridworld import Layout, load_layout
from pcpg_dist.errors import DataError
from pcpg_dist.pbtg import assemble_dataset, generate_pair, pair_seed
from pcpg_dist.provenance import provenance
from pcpg_dist.ray_utils import run_tasks


@dataclass(frozen=True, eq=False)
class Unit:
    """One evaluation unit: a dataset, its held-out trajectories, and the name results go under."""

    name: str
    dataset: Dataset
    test_idx: np.ndarray
    #: what Step A clusters, when it differs from ``dataset`` (same trajectories, same order)
    cluster_input: Dataset | None = None
    cluster_input_note: str = "raw"

    @property
    def clustered(self) -> Dataset:
        return self.cluster_input if self.cluster_input is not None else self.dataset


def gridworld_layouts(cfg: ExperimentConfig) -> list[Layout]:
    return [load_layout(cfg.gridworld.layout_path(env)) for env in cfg.gridworld.environments]


def _minidungeons_part(level: str, proxy: int, runs: int, seed: int, noise: tuple[float, float],
                       max_steps: int) -> Dataset:
    from pcpg_dist.domains.minidungeons import generate_trajectories, part_seed

    return generate_trajectories(level, proxy, runs, part_seed(seed, level, proxy), noise, max_steps)


def generate(cfg: ExperimentConfig, show_progress: bool = True) -> dict[str, Dataset]:
    """Every dataset file of the config's domain, keyed by env (Ray must be initialised)."""
    if cfg.domain == "gridworld":
        layouts = gridworld_layouts(cfg)
        calls = [(layout, r, cfg.pbtg, cfg.seed) for layout in layouts for r in range(4)]
        pairs = run_tasks(generate_pair, calls, "PBTG (E, R)", show_progress=show_progress)
        return {lt.name: assemble_dataset(pairs[4 * i: 4 * i + 4]) for i, lt in enumerate(layouts)}
    if cfg.domain == "minidungeons":
        from pcpg_dist.domains.minidungeons import N_PROXIES

        md = cfg.minidungeons
        levels = [*md.train_levels, *md.test_levels]
        calls = [(lv, p, md.runs_per_level, cfg.seed, (md.noise_min, md.noise_max), md.max_steps)
                 for lv in levels for p in range(N_PROXIES)]
        parts = run_tasks(_minidungeons_part, calls, "proxies (level, proxy)", show_progress=show_progress)
        return {lv: Dataset.concat(parts[i * N_PROXIES:(i + 1) * N_PROXIES], renumber=True)
                for i, lv in enumerate(levels)}
    from pcpg_dist.domains.mario import load

    result = load(cfg.mario)
    if result.skipped:
        from pcpg_dist.progress import console

        console.print(f"mario: {result.summary()}")
    return {result.dataset.env: result.dataset}


def generate_to(cfg: ExperimentConfig, out_dir: Path, show_progress: bool = True) -> dict[str, Dataset]:
    """Generate and write ``out_dir/<domain>-<env>.parquet`` + ``manifest.json``."""
    t0 = time.perf_counter()
    datasets = generate(cfg, show_progress)
    seeds = ({f"{env}/R{r + 1}": pair_seed(cfg.seed, env, r).entropy for env in datasets for r in range(4)}
             if cfg.domain == "gridworld" else {"base": cfg.seed})
    write_datasets(out_dir, list(datasets.values()), {
        "config": cfg.model_dump(mode="json"), "config_hash": cfg.hash(), "base_seed": cfg.seed,
        "seed_entropy": seeds, "generate_seconds": round(time.perf_counter() - t0, 3), **provenance(),
    })
    return datasets


def units(cfg: ExperimentConfig, datasets: dict[str, Dataset]) -> list[Unit]:
    """The evaluation units of a domain's datasets (see the module docstring)."""
    from pcpg_dist.ranking import split_trajectories

    if cfg.domain == "gridworld":
        return [Unit(env, ds, split_trajectories(ds.n_trajectories, cfg.ranking.test_fraction,
                                                   cfg.ranking.split_seed)[1])
                for env, ds in datasets.items()]
    if cfg.domain == "minidungeons":
        md = cfg.minidungeons
        missing = [lv for lv in (*md.train_levels, *md.test_levels) if lv not in datasets]
        if missing:
            raise DataError(f"minidungeons data has no level {missing[0]!r}")
        parts = [datasets[lv] for lv in (*md.train_levels, *md.test_levels)]
        joined = replace(Dataset.concat(parts), env="levels")
        n_train = sum(datasets[lv].n_trajectories for lv in md.train_levels)
        # Step A sees each level's states standardised within the level: in raw features a level's
        # size swamps play-style (LSTM+DEC 0.44 accuracy vs the proxies; per level 0.83).
        scaled = replace(Dataset.concat([_standardised(p) for p in parts]), env="levels")
        return [Unit("levels", joined, np.arange(n_train, joined.n_trajectories), scaled, "per-level-z")]
    from pcpg_dist.domains.mario import valid_mask_from, with_valid

    (env, ds), = datasets.items()
    train_idx, test_idx = split_trajectories(ds.n_trajectories, cfg.ranking.test_fraction,
                                             cfg.ranking.split_seed)
    return [Unit(env, with_valid(ds, valid_mask_from(ds.subset(train_idx))), test_idx)]


def _standardised(ds: Dataset) -> Dataset:
    """The dataset with every state feature standardised over its own rows (constant ones kept at 0)."""
    mean, std = ds.states.mean(axis=0), ds.states.std(axis=0)
    std = np.where(std > 1e-6, std, 1.0)
    return replace(ds, states=((ds.states - mean) / std).astype(np.float32))


def hooks(cfg: ExperimentConfig, unit: str):
    """Rollout/reward/drawing callables of a simulating domain (None where it cannot simulate)."""
    from pcpg_dist.evaluation import DomainHooks

    steps = cfg.evaluation.max_steps
    if cfg.domain == "gridworld":
        from pcpg_dist.domains import gridworld as gw

        layout = gw.load_layout(cfg.gridworld.layout_path(unit), check_styles=False)
        return DomainHooks(
            rollout=lambda policy, n, rng: gw.rollout(layout, policy, n, rng, max_steps=steps),
            returns=gw.returns, optimal_return=lambda r: gw.optimal_return(layout, r, max_steps=steps),
            draw=lambda ax, ds: gw.draw_trajectory(ax, layout, ds))
    if cfg.domain == "minidungeons":
        return DomainHooks(rollout=lambda policy, n, rng: minidungeons_rollout(cfg, policy, n, rng))
    return None


def minidungeons_rollout(cfg: ExperimentConfig, policy, n: int, rng: np.random.Generator) -> Dataset:
    """``n`` episodes spread evenly over the held-out levels."""
    from pcpg_dist.domains.minidungeons import rollout

    levels = cfg.minidungeons.test_levels
    counts = [n // len(levels) + (i < n % len(levels)) for i in range(len(levels))]
    parts = [rollout(lv, policy, c, rng, max_steps=cfg.minidungeons.max_steps)
             for lv, c in zip(levels, counts, strict=True) if c]
    return Dataset.concat(parts)
