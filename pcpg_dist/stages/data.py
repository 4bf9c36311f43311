"""Data for any registered domain: generated or loaded, written as Parquet + manifest.

What the data is and how it becomes evaluation units is the domain's business
(:class:`~pcpg_dist.domains.base.Domain`); this module writes it down with its provenance.
"""

from __future__ import annotations

import time
from pathlib import Path

from pcpg_dist.common.provenance import provenance
from pcpg_dist.config import ExperimentConfig
from pcpg_dist.dataset import Dataset, write_datasets
from pcpg_dist.domains import contract
from pcpg_dist.domains.base import FanOut, Unit
from pcpg_dist.domains.defaults import in_process

__all__ = ["Unit", "generate", "generate_to", "units"]


def generate(
    cfg: ExperimentConfig, show_progress: bool = True, fan_out: FanOut = in_process
) -> dict[str, Dataset]:
    """Every dataset file of the config's domain, keyed by env; the domain's batches of calls go
    through ``fan_out`` (the orchestration passes its Ray fan-out; by default they run here)."""
    return contract.generate(cfg, show_progress, fan_out)


def generate_to(
    cfg: ExperimentConfig, out_dir: Path, show_progress: bool = True, fan_out: FanOut = in_process
) -> dict[str, Dataset]:
    """Generate and write ``out_dir/<domain>-<env>.parquet`` + ``manifest.json``."""
    t0 = time.perf_counter()
    datasets = generate(cfg, show_progress, fan_out)
    write_to(cfg, datasets, out_dir, time.perf_counter() - t0)
    return datasets


def write_to(
    cfg: ExperimentConfig, datasets: dict[str, Dataset], out_dir: Path, seconds: float | None = None
) -> Path:
    """Write the datasets and their manifest (config, seeds, provenance) to ``out_dir``."""
    return write_datasets(
        out_dir,
        list(datasets.values()),
        {
            "config": cfg.model_dump(mode="json"),
            "config_hash": cfg.hash(),
            "base_seed": cfg.seed,
            **contract.manifest(cfg, datasets),
            "generate_seconds": None if seconds is None else round(seconds, 3),
            **provenance(),
        },
    )


def units(cfg: ExperimentConfig, datasets: dict[str, Dataset]) -> list[Unit]:
    """The evaluation units of a domain's datasets (split, valid sets, what Step A clusters)."""
    return contract.units(cfg, datasets)
