"""`pcpg run`: generate → cluster → rank/threshold → train → evaluate → log, fanned out on Ray.

Every unit of work has a content key (its config slice + its inputs' keys) and a cache folder
(:mod:`pcpg_dist.cache`); a finished unit is never recomputed, so rerunning the same command after
Ctrl-C or a killed process continues where it stopped and ends with the same numbers.

Units: the data (one Ray task per (environment, style)), one clustering per environment, BC
training in groups of ``runner.group_size`` cells (never one task per tiny model), one evaluation
per environment. MLflow comes last: one logging task per environment (its child run, from the
worker) once every local result is written, so a tracking server that goes down costs no work.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pcpg_dist.cache import Cache, content_key
from pcpg_dist.config import ExperimentConfig
from pcpg_dist.dataset import Dataset, atomic_write_bytes, confined, load_datasets
from pcpg_dist.domains.base import Unit
from pcpg_dist.parallel import set_threads
from pcpg_dist.ray_utils import run_tasks

CODE_VERSION = "2"  # bump when a stage's numbers or files change for the same config (2: bool valid masks)


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


def _collect_agents(target: Path, models: dict[str, list[Path]]) -> Path:
    """``target/<env>/<group>.pt|.json``: every trained cell of the sweep, for the pyfunc model."""
    import shutil

    if target.exists():
        shutil.rmtree(target)
    for env, paths in models.items():
        (target / env).mkdir(parents=True)
        for i, p in enumerate(paths):
            for suffix in (".pt", ".json"):
                shutil.copyfile(p.with_suffix(suffix), target / env / f"group{i:03d}{suffix}")
    return target


# --------------------------------------------------------------------------- data
def data_key(cfg: ExperimentConfig) -> str:
    """Content key of the data: what the domain says identifies it (settings, file contents, seed)."""
    return content_key(CODE_VERSION, *cfg.domain_object.data_key(cfg))


def load_or_generate(cfg: ExperimentConfig, cache: Cache, show_progress: bool) -> tuple[dict[str, Dataset], str]:
    from pcpg_dist.generate import write_to

    key = data_key(cfg)
    path = cache.path("data", key)
    if cache.done("data", key) is None:
        # generated and validated in memory first: bad input leaves nothing behind
        datasets = cfg.domain_object.generate(cfg, show_progress)
        cache.start("data", key)
        write_to(cfg, datasets, path)
        cache.finish("data", key, {"stage": "data"})
    return load_datasets(path), key


def load_units(cfg: ExperimentConfig, cache: Cache, show_progress: bool) -> tuple[list[Unit], str]:
    """The config's evaluation units (data generated or loaded once, then cached) and the data key."""
    files, key = load_or_generate(cfg, cache, show_progress)
    return cfg.domain_object.units(cfg, files), key


# --------------------------------------------------------------------------- Ray tasks
def cluster_task(unit: Unit, cfg, seed: int, threads: int, out_dir: str) -> dict:
    """One unit's clustering (a Ray task): labels, metrics and the saved model."""
    from pcpg_dist.pipeline import cluster_unit

    set_threads(threads)
    result = cluster_unit(unit, cfg, seed)
    if result.model is not None:
        result.model.save(Path(out_dir) / "model")
    return {"labels": result.labels.tolist(), "metrics": result.metrics}


def train_task(cells: list, cfg, threads: int, out_path: str) -> str:
    """Train one group of cells in one vectorised pass (a Ray task); saves and returns the path."""
    from pcpg_dist.bc import train_cells

    set_threads(threads)
    return str(train_cells(cells, cfg).save(out_path))


def evaluate_task(unit: Unit, labels: np.ndarray, model_paths: list[str], cfg: ExperimentConfig,
                  out_dir: str, threads: int) -> dict:
    """Evaluate one unit (a Ray task); its tables and ``metrics.json`` go to ``out_dir``."""
    from pcpg_dist.bc import TrainedCells
    from pcpg_dist.pipeline import evaluate_unit

    set_threads(threads)
    trained = TrainedCells.concat([TrainedCells.load(p) for p in model_paths])
    metrics = evaluate_unit(unit, labels, trained, cfg, out_dir)
    atomic_write_bytes(Path(out_dir) / "metrics.json", json.dumps(metrics, indent=1, sort_keys=True).encode())
    return metrics


def log_task(tracking: dict, env: str, out_dir: str, metrics: dict[str, float], model_paths: list[str]) -> str:
    """Log one finished evaluation as the environment's MLflow child run (a Ray task, on the worker).

    Separate from :func:`evaluate_task` so that an unreachable tracking server never costs the
    evaluation: its unit is done and kept, and a rerun only logs it.
    """
    from pcpg_dist.tracking import log_environment

    return log_environment(tracking, env, out_dir, metrics, model_paths)


# --------------------------------------------------------------------------- the run
def run_experiment(cfg: ExperimentConfig, workdir: Path = Path("runs"), tracking_uri: str | None = None,
                   track: bool = True, show_progress: bool = True, command: str = "") -> RunResult:
    """Run (or resume) a whole experiment; Ray must be initialised by the caller."""
    from pcpg_dist.bc import TrainedCells  # noqa: F401 - import torch once in the driver
    from pcpg_dist.pipeline import plan_unit

    out = Path(workdir).resolve() / cfg.name
    cache = Cache(out / "cache")
    threads = cfg.runner.cpus_per_task
    times: dict[str, float] = {}
    computed: dict[str, int] = {"clustering": 0, "train_groups": 0, "evaluations": 0}
    # Data first: a bad input file fails here, before any MLflow run or cache entry exists.
    t0 = time.perf_counter()
    the_units, dkey = load_units(cfg, cache, show_progress)
    by_name = {u.name: u for u in the_units}
    for name in by_name:
        confined(out, name, "unit name")  # unit names become folder and run names
    times["generate"] = time.perf_counter() - t0
    tracker = None
    if track:
        from pcpg_dist.tracking import Tracker

        tracker = Tracker.start(cfg, tracking_uri, out)

    try:

        # ---- Step A: one clustering per environment
        t0 = time.perf_counter()
        envs = list(by_name)
        ckeys = {e: content_key(CODE_VERSION, dkey, e, cfg.clustering, cfg.seed, by_name[e].cluster_input_note)
                 for e in envs}
        todo = [e for e in envs if cache.done("cluster", ckeys[e]) is None]
        for e in todo:
            cache.start("cluster", ckeys[e])

        def save_cluster(i: int, res: dict) -> None:
            e = todo[i]
            path = cache.path("cluster", ckeys[e])
            atomic_write_bytes(path / "result.json", json.dumps(res).encode())
            cache.finish("cluster", ckeys[e], {"env": e})

        run_tasks(cluster_task, [(by_name[e], cfg.clustering, cfg.seed, threads,
                                  str(cache.path("cluster", ckeys[e]))) for e in todo],
                  "Step A: clustering", num_cpus=threads, on_result=save_cluster,
                  show_progress=show_progress and bool(todo))
        computed["clustering"] = len(todo)
        clusters = {e: json.loads((cache.path("cluster", ckeys[e]) / "result.json").read_text()) for e in envs}
        times["cluster"] = time.perf_counter() - t0

        # ---- Steps B + C: plan every cell, train in groups
        t0 = time.perf_counter()
        groups: list[tuple[str, str, list]] = []  # (env, key, cells)
        labels_of = {e: np.asarray(clusters[e]["labels"], np.int64) for e in envs}
        for e in envs:
            cells = plan_unit(by_name[e], labels_of[e], cfg)
            size = cfg.runner.group_size
            for g in range(0, len(cells), size):
                chunk = cells[g: g + size]
                key = content_key(CODE_VERSION, ckeys[e], cfg.ranking, cfg.bc, cfg.evaluation.corruption_levels,
                                  cfg.evaluation.corruption_ps, [c.key for c in chunk])
                groups.append((e, key, chunk))
        pending = [(e, k, c) for e, k, c in groups if cache.done("train", k) is None]
        for _, k, _ in pending:
            cache.start("train", k)

        def save_group(i: int, path: str) -> None:
            cache.finish("train", pending[i][1], {"env": pending[i][0], "cells": len(pending[i][2])})

        run_tasks(train_task, [(c, cfg.bc, threads, str(cache.path("train", k) / "cells")) for _, k, c in pending],
                  "Step C: BC groups", num_cpus=threads, on_result=save_group,
                  show_progress=show_progress and bool(pending))
        computed["train_groups"] = len(pending)
        times["train"] = time.perf_counter() - t0

        # ---- Evaluation per environment (MLflow child runs are logged after the summary)
        t0 = time.perf_counter()
        ekeys = {e: content_key(CODE_VERSION, [k for ge, k, _ in groups if ge == e], cfg.evaluation,
                                cfg.ranking) for e in envs}
        models = {e: [str(cache.path("train", k) / "cells.pt") for ge, k, _ in groups if ge == e] for e in envs}
        todo = [e for e in envs if cache.done("evaluate", ekeys[e]) is None]
        for e in todo:
            cache.start("evaluate", ekeys[e])
        calls = [(by_name[e], labels_of[e], models[e], cfg, str(cache.path("evaluate", ekeys[e])), threads)
                 for e in todo]

        def save_eval(i: int, metrics: dict) -> None:
            cache.finish("evaluate", ekeys[todo[i]], {"env": todo[i]})

        run_tasks(evaluate_task, calls, "Evaluation", num_cpus=threads, on_result=save_eval,
                  show_progress=show_progress and bool(todo))
        computed["evaluations"] = len(todo)
        per_env = {e: json.loads((cache.path("evaluate", ekeys[e]) / "metrics.json").read_text()) for e in envs}
        times["evaluate"] = time.perf_counter() - t0

        # ---- Across environments: summary tables, figures, parent-run logging, report
        t0 = time.perf_counter()
        from pcpg_dist.summary import write_summary

        metrics = write_summary(cfg, out, {e: cache.path("evaluate", ekeys[e]) for e in envs}, per_env,
                                {e: clusters[e]["metrics"] for e in envs})
        agents = _collect_agents(out / "agents", {e: [cache.path("train", k) / "cells" for ge, k, _ in groups
                                                      if ge == e] for e in envs})
        times["summary"] = time.perf_counter() - t0
        result = RunResult(out_dir=out, metrics=metrics, clustering={e: clusters[e]["metrics"] for e in envs},
                           stage_seconds=times, computed=computed,
                           parent_run_id=tracker.parent_id if tracker else None)
        from pcpg_dist.provenance import provenance
        from pcpg_dist.report import render

        run_info = {"config": cfg.model_dump(mode="json"), "config_hash": cfg.hash(), "command": command
                    or f"pcpg run <config of {cfg.name}>", "provenance": provenance(), "stage_seconds": times,
                    "parent_run_id": result.parent_run_id, "computed": computed}
        atomic_write_bytes(out / "summary" / "run.json", json.dumps(run_info, indent=1, default=str).encode())
        result.report = render(out / "summary", out / "report")[0]
        if tracker is not None:
            # Last, so that every local result above is kept when the server is down; a rerun
            # logs only the environments without a FINISHED child run, recomputing nothing.
            unlogged = [e for e in envs if not tracker.env_logged(e, ekeys[e])]
            run_tasks(log_task, [(tracker.child_info(e, ekeys[e], clusters[e]["metrics"]), e,
                                  str(cache.path("evaluate", ekeys[e])), per_env[e], models[e]) for e in unlogged],
                      "MLflow child runs", num_cpus=1, show_progress=show_progress and bool(unlogged))
            tracker.finish(result, agents_dir=agents, report_dir=out / "report")
        return result
    except BaseException:
        if tracker is not None:
            tracker.fail()
        raise
