"""What the runner works on: points (one config each, with where its outputs go), the data stage
that gives each point its evaluation units, and what a point's stages leave for the hooks."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pcpg_dist.config import ExperimentConfig
from pcpg_dist.dataset import Dataset, load_datasets
from pcpg_dist.domains import contract
from pcpg_dist.domains.base import FanOut, Unit
from pcpg_dist.orchestration import ray_pool
from pcpg_dist.orchestration.cache import Cache
from pcpg_dist.orchestration.executors import Executor
from pcpg_dist.pipeline.declared import data_key


@dataclass
class RunResult:
    """What `pcpg run` produced: where, the summary metrics, and where time went."""

    out_dir: Path
    metrics: dict[str, float]
    clustering: dict[str, dict[str, float]]
    stage_seconds: dict[str, float] = field(default_factory=dict)
    parent_run_id: str | None = None
    computed: dict[str, int] = field(default_factory=dict)
    report: Path | None = None
    cached_stages: list[str] = field(default_factory=list)
    method: str | None = None  # the clusterer, where it is not clustering.method (a streamed run)


@dataclass
class Point:
    """One config to run: where its outputs go and (in a sweep) what it overrides."""

    cfg: ExperimentConfig
    out: Path
    params: dict[str, str] = field(default_factory=dict)
    command: str = ""
    # filled while running
    units: dict[str, Unit] = field(default_factory=dict)
    refs: dict[str, Any] = field(default_factory=dict)
    digests: dict[str, str] = field(
        default_factory=dict
    )  # what each unit's clusterer reads, hashed
    dkey: str = ""
    ikey: str = ""  # the inputs' key, recorded in run.json (data_keys)
    ckeys: dict[str, str] = field(default_factory=dict)
    groups: list[tuple[str, str, list]] = field(default_factory=list)  # (env, train key, cells)
    ekeys: dict[str, str] = field(default_factory=dict)
    gpus: tuple[float, float] = (0.0, 0.0)  # what a (clustering, BC) task asks Ray for
    tracker: Any = None  # set by a tracking hook

    def train_keys(self, env: str) -> list[str]:
        """The keys of ``env``'s trained groups, in training order."""
        return [k for ge, k, _ in self.groups if ge == env]


@dataclass
class Outcome:
    """What the stages left for one point: everything in the cache, found by the point's keys.

    ``times`` and ``computed`` are the batch's (a sweep's points run their stages together);
    ``batch`` is how many points ran in it."""

    point: Point
    cache: Cache
    clusters: dict[str, dict]
    times: dict[str, float]
    computed: dict[str, int]
    batch: int = 1
    executor: Executor | None = None  # what ran the stages (and runs the child-run logging)

    def cluster_result(self, env: str) -> dict:
        return self.clusters[self.point.ckeys[env]]

    def eval_dir(self, env: str) -> Path:
        return self.cache.path("evaluate", self.point.ekeys[env])

    def eval_metrics(self, env: str) -> dict[str, float]:
        return self.cache.read_json("evaluate", self.point.ekeys[env], "metrics.json")

    def trained_cells(self, env: str) -> list[Path]:
        """The folders of ``env``'s trained groups (``<key>/cells``)."""
        return [self.cache.path("train", k) / "cells" for k in self.point.train_keys(env)]


def clusters_of(result: dict) -> tuple[np.ndarray, np.ndarray | None]:
    """A cached clustering's labels and margins (None from a clusterer without a likelihood)."""
    margins = result.get("margins")
    return (
        np.asarray(result["labels"], np.int64),
        None if margins is None else np.asarray(margins, np.float64),
    )


# --------------------------------------------------------------------------- the data stage
def load_or_generate(
    cfg: ExperimentConfig,
    cache: Cache,
    show_progress: bool,
    key: str | None = None,
    fan_out: FanOut | None = None,
) -> tuple[dict[str, Dataset], str]:
    """The config's datasets, generated once and cached under ``key`` (its :func:`data_key`);
    the domain's batches of work go through ``fan_out`` (default: as Ray tasks)."""
    from pcpg_dist.stages.data import write_to

    key = key or data_key(cfg)
    path = cache.path("data", key)
    if cache.done("data", key) is None:
        # generated and validated in memory first: bad input leaves nothing behind
        datasets = contract.generate(cfg, show_progress, fan_out=fan_out or ray_pool.fan_out)
        cache.start("data", key)
        write_to(cfg, datasets, path)
        cache.finish("data", key, {"stage": "data"})
    return load_datasets(path), key


def load_units(cfg: ExperimentConfig, cache: Cache, show_progress: bool) -> tuple[list[Unit], str]:
    """The config's evaluation units (data generated or loaded once, then cached) and the data key."""
    files, key = load_or_generate(cfg, cache, show_progress)
    units = contract.units(cfg, files)
    warn_partial_styles(units)
    return units, key


def warn_partial_styles(units: list[Unit]) -> None:
    """One warning line per unit whose styles are known for some trajectories only."""
    from pcpg_dist.pipeline import partial_styles_note

    for unit in units:
        if note := partial_styles_note(unit):
            logging.getLogger(__name__).warning("%s", note)
