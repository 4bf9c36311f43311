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

    set_threads(threads)
    result = cluster_unit(unit, cluster_cfg, seed)
    model: dict[str, bytes] = {}
    if result.model is not None:
        with tempfile.TemporaryDirectory() as tmp:
            result.model.save(Path(tmp))
            model = files_of(tmp)
    margins = None if result.margins is None else result.margins.tolist()
    return {
        "labels": result.labels.tolist(),
        "margins": margins,
        "metrics": result.metrics,
        "model": model,
    }


def train_task(cells: list, bc_cfg, threads: int, init: list | None = None):
    """Train one group of cells in one vectorised pass; returns the trained arrays.
    ``init``: the cells' starting parameters (``bc.init: no_clustering``)."""
    from pcpg_dist.stages.bc import train_cells

    set_threads(threads)
    return train_cells(cells, bc_cfg, init)


def evaluate_task(
    unit: Unit,
    labels: np.ndarray,
    trained,
    cfg,
    threads: int,
    margins: np.ndarray | None = None,
) -> dict:
    """Evaluate one unit: its metrics and its tables and figures as bytes."""
    from pcpg_dist.pipeline.units import evaluate_unit

    set_threads(threads)
    with tempfile.TemporaryDirectory() as tmp:
        metrics = evaluate_unit(unit, labels, trained, cfg, tmp, margins=margins)
        files = files_of(tmp)
    files["metrics.json"] = json.dumps(metrics, indent=1, sort_keys=True).encode()
    return {"metrics": metrics, "files": files}
