"""`pcpg run` on a log too large for one process: the streamed pipeline
(:mod:`pcpg_dist.orchestration.streaming`), its outputs and its MLflow run.

Outputs, under ``RUN/summary``: ``streamed.json`` (metrics, clustering quality, seconds per
stage, sizes, epochs per BC group), ``labels_seed<S>.parquet`` (trajectory, held out, cluster,
the ranking code) and ``agents_seed<S>.npz`` (every cell's weights, as plain arrays). The label
files are written batch by batch as the engine streams them, to a temporary name renamed when
complete, so the driver never holds the labels of the whole log.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from pcpg_dist.common.files import atomic_write_bytes
from pcpg_dist.common.progress import progress_bar
from pcpg_dist.domains.base import StreamSource
from pcpg_dist.orchestration.points import RunResult


def log_digest(source: StreamSource) -> str:
    """The log's identity for lineage: every file's name, size and modification time (hashing
    the content of a multi-GB log would cost more than a pass of the run)."""
    parts = [[Path(f).name, os.stat(f).st_size, os.stat(f).st_mtime_ns] for f in source.files]
    return hashlib.sha256(json.dumps(parts).encode()).hexdigest()[:16]


def run_streamed(
    cfg,
    source: StreamSource,
    out: Path,
    tracking_uri: str | None,
    track: bool,
    show_progress: bool,
    command: str,
) -> RunResult:
    from pcpg_dist.orchestration.ray_pool import node_capacities
    from pcpg_dist.orchestration.streaming import STEPS_PER_SEED, stream_unit

    node_cpus = [int(n["CPU"]) for n in node_capacities()]
    with progress_bar(
        "Streamed: features", 1 + STEPS_PER_SEED * len(cfg.seeds), enabled=show_progress
    ) as advance:
        result = stream_unit(source, cfg, node_cpus, advance)
    summary = out / "summary"
    summary.mkdir(parents=True, exist_ok=True)
    for seed, labels in result.labels.items():
        _write_labels(labels, summary / f"labels_seed{seed}.parquet")
        arrays = {
            f"cell{'nc' if c < 0 else c}_p{cfg.ranking.ps[pi]:g}_{j}": a
            for (c, pi), state in zip(result.cells[seed], result.weights[seed], strict=True)
            for j, a in enumerate(state)
        }
        _write_npz(summary / f"agents_seed{seed}.npz", arrays)
    record = {
        "streamed": True,
        "log": list(source.files),
        "n_trajectories": result.n_trajectories,
        "steps": result.steps,
        "metrics": result.metrics,
        "clustering": result.clustering,
        "stage_seconds": result.seconds,
        "bc_epochs": {str(s): e for s, e in result.epochs.items()},
    }
    atomic_write_bytes(summary / "streamed.json", json.dumps(record, indent=1).encode())
    run_id = None
    if track:
        from pcpg_dist.tracking.datasets import data_inputs
        from pcpg_dist.tracking.streamed import log_streamed

        metrics = {**result.metrics, **result.clustering}
        metrics.update({f"seconds/{k}": v for k, v in result.seconds.items()})
        run_id = log_streamed(
            tracking_uri,
            cfg,
            metrics,
            summary / "streamed.json",
            data_inputs(cfg, log_digest(source)),
            command,
        )
    return RunResult(
        out_dir=out,
        metrics=result.metrics,
        clustering={source.name: result.clustering},
        stage_seconds=result.seconds,
        parent_run_id=run_id,
        method="streamed k-means",
    )


def _write_labels(labels, path: Path) -> None:
    import pyarrow.parquet as pq

    tmp = path.with_name(path.name + ".part")
    writer = None
    try:
        for table in labels.iter_batches(batch_format="pyarrow", batch_size=None):
            if writer is None:
                writer = pq.ParquetWriter(tmp, table.schema)
            writer.write_table(table)
    finally:
        if writer is not None:
            writer.close()
    os.replace(tmp, path)


def _write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    import io

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())
