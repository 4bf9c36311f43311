"""Data generation for every domain, fanned out on Ray: one task per (environment, style)."""

from __future__ import annotations

import time
from pathlib import Path

from pcpg_dist.config import ExperimentConfig
from pcpg_dist.dataset import Dataset, write_datasets
from pcpg_dist.domains.gridworld import Layout, load_layout
from pcpg_dist.errors import ConfigError
from pcpg_dist.pbtg import assemble_dataset, generate_pair, pair_seed
from pcpg_dist.provenance import provenance
from pcpg_dist.ray_utils import run_tasks


def gridworld_layouts(cfg: ExperimentConfig) -> list[Layout]:
    return [load_layout(cfg.gridworld.layout_path(env)) for env in cfg.gridworld.environments]


def generate(cfg: ExperimentConfig, show_progress: bool = True) -> dict[str, Dataset]:
    """Every environment's dataset D for the config's domain (Ray must be initialised)."""
    if cfg.domain != "gridworld":
        raise ConfigError(f"key 'domain': generation for {cfg.domain!r} is not available in this build")
    layouts = gridworld_layouts(cfg)
    calls = [(layout, r, cfg.pbtg, cfg.seed) for layout in layouts for r in range(4)]
    pairs = run_tasks(generate_pair, calls, "PBTG (E, R)", show_progress=show_progress)
    return {layout.name: assemble_dataset(pairs[4 * i: 4 * i + 4]) for i, layout in enumerate(layouts)}


def generate_to(cfg: ExperimentConfig, out_dir: Path, show_progress: bool = True) -> dict[str, Dataset]:
    """Generate and write ``out_dir/<domain>-<env>.parquet`` + ``manifest.json``."""
    t0 = time.perf_counter()
    datasets = generate(cfg, show_progress)
    seeds = {f"{env}/R{r + 1}": pair_seed(cfg.seed, env, r).entropy for env in datasets for r in range(4)}
    write_datasets(out_dir, list(datasets.values()), {
        "config": cfg.model_dump(mode="json"), "config_hash": cfg.hash(), "base_seed": cfg.seed,
        "seed_entropy": seeds, "generate_seconds": round(time.perf_counter() - t0, 3), **provenance(),
    })
    return datasets
