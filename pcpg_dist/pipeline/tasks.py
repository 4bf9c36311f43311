"""The work of one job of each stage, as plain functions of values: what a Ray task (or the
in-process executor) runs. No Ray, no cache, no MLflow: inputs come as arguments, results go back
as values (labels, metrics, trained arrays, files as ``{relative path: bytes}``), so no worker
needs the driver's disk."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from pcpg_dist.common.devices import set_threads
from pcpg_dist.common.file_bytes import files_of
from pcpg_dist.domains.base import Unit


def cluster_task(unit: Unit, cluster_cfg, seed: int, threads: int) -> dict:
    """One unit's clustering: labels, margins, metrics and the fitted model's files as bytes."""
    from pcpg_dist.pipeline.units import cluster_unit
    from pcpg_dist.stages.clustering.style_weights import style_weights_of

    set_threads(threads)
    result = cluster_unit(unit, cluster_cfg, seed)
    model: dict[str, bytes] = {}
    if result.model is not None:
        with tempfile.TemporaryDirectory() as tmp:
            result.model.save(Path(tmp))
            model = files_of(tmp)
    margins = None if result.margins is None else result.margins.tolist()
    weights = style_weights_of(result.model)  # what each cluster weighs, by the moves' features
    return {
        "labels": result.labels.tolist(),
        "margins": margins,
        "metrics": result.metrics,
        "model": model,
        "style_weights": None if weights is None else weights.to_csv(index=False),
    }


def train_task(
    unit: Unit,
    labels: np.ndarray,
    margins: np.ndarray | None,
    cfg,
    keys: list[str],
    bc_cfg,
    threads: int,
    base: list[dict[str, bytes]] | None = None,
) -> dict:
    """Build one group of cells (Step B for the cells of ``keys`` of the unit's plan, here and
    not in the driver) and train them in one vectorised pass; returns the trained ensemble's
    files (:meth:`~pcpg_dist.stages.bc.TrainedCells.to_files`: the driver only writes them).
    ``base``: the files of the unit's No Clustering agents (``bc.init: no_clustering``): each
    cell starts from the one of its p and seed (:func:`~pcpg_dist.stages.bc.init_from`) and is
    fine-tuned by :func:`~pcpg_dist.stages.bc.finetune_cells`, which checks a fine-tune against
    the No Clustering cells under ``bc.init: auto``. Read here, so the driver needs no torch."""
    from pcpg_dist.pipeline.units import plan_unit
    from pcpg_dist.stages.bc import TrainedCells, bases_of, finetune_cells, init_from, train_cells
    from pcpg_dist.stages.bc.finetune import checks

    set_threads(threads)
    checked = base is not None and checks(bc_cfg)  # the starts' No Clustering cells too
    extra = nc_keys(unit, labels, cfg, margins) if checked else []
    every = plan_unit(unit, labels, cfg, margins=margins, only=keys + extra)
    wanted = set(keys)
    cells = [c for c in every if c.spec.key in wanted]
    if base is None:
        trained = train_cells(cells, bc_cfg)
    else:
        init = init_from(cells, TrainedCells.from_files(base))
        bases = bases_of(cells, every) if checked else None
        trained = finetune_cells(cells, bc_cfg, init, bases, cfg.bc)
    return {"files": trained.to_files(), "cells": len(trained.specs)}


def nc_keys(unit: Unit, labels: np.ndarray, cfg, margins: np.ndarray | None) -> list[str]:
    """The keys of the unit's No Clustering cells."""
    from pcpg_dist.pipeline.units import plan_unit_specs

    return [s.key for s in plan_unit_specs(unit, labels, cfg, margins=margins) if s.kind == "nc"]


def evaluate_task(
    unit: Unit,
    labels: np.ndarray,
    trained: list[dict[str, bytes]],
    cfg,
    threads: int,
    margins: np.ndarray | None = None,
    model_files: dict[str, bytes] | None = None,
) -> dict:
    """Evaluate one unit: its metrics and its tables and figures as bytes. ``trained``: the
    files of each of its train units (:meth:`~pcpg_dist.stages.bc.TrainedCells.to_files`, read
    here, not in the driver). ``model_files``: the fitted clustering's files (what `pcpg classify`
    reads), to classify the agents' rollouts."""
    from pcpg_dist.common.file_bytes import write_files
    from pcpg_dist.pipeline.units import evaluate_unit
    from pcpg_dist.stages.bc import TrainedCells
    from pcpg_dist.stages.clustering.model_io import load_model

    set_threads(threads)
    model = None
    if model_files:
        with tempfile.TemporaryDirectory() as tmp:
            write_files(Path(tmp), model_files)
            model = load_model(tmp, move_features=cfg.clustering.move_features)
    cells = TrainedCells.from_files(trained)
    with tempfile.TemporaryDirectory() as tmp:
        metrics = evaluate_unit(unit, labels, cells, cfg, tmp, margins=margins, model=model)
        files = files_of(tmp)
    files["metrics.json"] = json.dumps(metrics, indent=1, sort_keys=True).encode()
    return {"metrics": metrics, "files": files}
