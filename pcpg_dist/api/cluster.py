"""`pcpg cluster`: the declared pipeline's data and Step A alone, one clustering model, labels
and metrics per environment in a folder of the user's choosing (no cache, no tracking)."""

from __future__ import annotations

import json
from pathlib import Path

from pcpg_dist.common.file_bytes import write_files
from pcpg_dist.common.files import atomic_write_bytes, confined
from pcpg_dist.config import ExperimentConfig
from pcpg_dist.orchestration.executors import Executor, RayExecutor
from pcpg_dist.orchestration.resources import cluster_gpus, unit_cluster_gpus
from pcpg_dist.pipeline.declared import CLUSTER


def cluster(
    cfg: ExperimentConfig,
    out: Path,
    data: Path | None = None,
    show_progress: bool = True,
    executor: Executor | None = None,
) -> dict[str, dict]:
    """Cluster every unit of ``cfg`` (its data generated into ``out/data``, or read from
    ``data``); writes ``out/<env>/{model/, labels.json, margins.json, metrics.json}`` (and
    ``style_weights.csv`` for a clustering by the moves' features) and returns
    each environment's Step A result (labels, margins, metrics)."""
    from pcpg_dist.dataset import load_datasets
    from pcpg_dist.domains import contract
    from pcpg_dist.pipeline.checks import check_apart_from_inputs
    from pcpg_dist.stages.data import generate_to

    executor = executor or RayExecutor()
    gpus = cluster_gpus(cfg, executor.most_gpus())  # a GPU setting no node can serve fails here
    out = Path(out)
    check_apart_from_inputs(cfg, out, "--out")
    if data:
        datasets = load_datasets(Path(data))
    else:
        datasets = generate_to(cfg, out / "data", show_progress, executor.fan_out)
    # the same units (split, per-level scaling, valid sets) as `pcpg run` clusters
    units = {u.name: u for u in contract.units(cfg, datasets)}
    envs = list(units)
    folders = {e: confined(out, e, "unit name") for e in envs}
    results: dict[str, dict] = {}

    def save(i: int, res: dict) -> None:
        _write_clustering(folders[envs[i]], res)
        results[envs[i]] = res

    executor.check(cfg.runner.cpus_per_task)
    executor.map(
        CLUSTER.function(),
        [(units[e], cfg.clustering, cfg.seed, cfg.runner.cpus_per_task) for e in envs],
        CLUSTER.description,
        num_cpus=cfg.runner.cpus_per_task,
        on_result=save,
        show_progress=show_progress,
        num_gpus=[unit_cluster_gpus(gpus, cfg.clustering, units[e].clustered) for e in envs],
    )
    return {e: results[e] for e in envs}


def _write_clustering(folder: Path, res: dict) -> None:
    write_files(folder / "model", res["model"])
    atomic_write_bytes(folder / "labels.json", json.dumps(res["labels"]).encode())
    if res["margins"] is not None:  # nats to the next-best cluster (a likelihood clusterer)
        atomic_write_bytes(folder / "margins.json", json.dumps(res["margins"]).encode())
    else:  # never an earlier clustering's margins beside these labels
        (folder / "margins.json").unlink(missing_ok=True)
    atomic_write_bytes(folder / "metrics.json", json.dumps(res["metrics"], indent=1).encode())
    weights = folder / "style_weights.csv"  # what each cluster weighs (a choice_mix clustering)
    if res.get("style_weights"):
        atomic_write_bytes(weights, res["style_weights"].encode())
    else:  # never an earlier clustering's weights beside these labels
        weights.unlink(missing_ok=True)
