"""`pcpg run` on a log too large for one process: the streamed pipeline
(:mod:`pcpg_dist.orchestration.streaming`), its outputs and its MLflow run.

Outputs, under ``RUN/summary``: ``streamed.json`` (metrics, clustering quality, seconds per
stage, sizes, epochs per BC group), ``labels_seed<S>.parquet`` (trajectory, held out, cluster,
the ranking code), ``agents_seed<S>.npz`` (every cell's weights, as plain arrays) and
``model_seed<S>/`` (the clustering, for `pcpg classify` on other logs). The label
files are written batch by batch as the engine streams them, to a temporary name renamed when
complete, so the driver never holds the labels of the whole log.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from pcpg_dist.common.errors import ConfigError, DataError
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
    from pcpg_dist.orchestration.nodes import node_capacities
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
        result.models[seed].save(summary / f"model_seed{seed}")  # what `pcpg classify` reads
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
    """A ``ray.data`` table to ``path`` (Parquet, or CSV where the name ends in .csv) batch by
    batch, under a temporary name renamed when complete."""
    import pyarrow.csv as pcsv
    import pyarrow.parquet as pq

    tmp = path.with_name(path.name + ".part")
    writer = None
    try:
        for table in labels.iter_batches(batch_format="pyarrow", batch_size=None):
            if writer is None:
                csv = path.suffix.lower() == ".csv"
                writer = (pcsv.CSVWriter if csv else pq.ParquetWriter)(tmp, table.schema)
            writer.write_table(table)
    finally:
        if writer is not None:
            writer.close()
    os.replace(tmp, path)


def classify_streamed(model: Path, log: Path, out: Path | None):
    """`pcpg classify` with a streamed run's clustering (``RUN/summary/model_seed<S>``): every
    trajectory of the Parquet ``log`` labelled block by block, the labels written to ``out``
    (CSV, or Parquet by its name) batch by batch; the driver holds only the k cluster sizes.
    Returns them as a table (``predicted_style``, ``trajectories``); ``attrs`` carry
    ``against_styles`` (where the log has styles), ``trajectories`` and ``out``."""
    import pandas as pd

    from pcpg_dist.domains.trajectories.settings import TrajectoriesConfig
    from pcpg_dist.domains.trajectories.stream_meta import stream_source
    from pcpg_dist.orchestration.ray_pool import init_ray
    from pcpg_dist.orchestration.streaming.engine import engine_errors, quiet_engine
    from pcpg_dist.orchestration.streaming.steps import classify_log, clustering_quality
    from pcpg_dist.stages.streamed.model import load_streamed_model

    fitted = load_streamed_model(model)
    if out is None:
        raise ConfigError(
            f"{model} is a streamed run's clustering: it labels logs too large to hold in memory, "
            f"so name the file for the labels (--out / out=, .csv or .parquet)"
        )
    settings = TrajectoriesConfig(path=str(log), stream="on", n_actions=fitted.n_actions)
    source = stream_source(settings, Path(log).stem)
    if list(source.states) != fitted.states:
        raise DataError(
            f"{log}: state columns {_columns(source.states)}; the model {model} was fitted on "
            f"{_columns(fitted.states)}, which a log it labels must have"
        )
    init_ray()
    quiet_engine()
    with engine_errors():
        labels, sizes, contingency = classify_log(source, fitted)
        _write_labels(labels.select_columns(["trajectory", "predicted_style"]), Path(out))
    table = pd.DataFrame({"predicted_style": range(fitted.k), "trajectories": sizes.astype(int)})
    table.attrs.update(
        streamed=True,
        out=str(out),
        trajectories=int(sizes.sum()),
        unknown_rows=None,
        against_styles=clustering_quality(contingency) or None,
    )
    return table


def _columns(names) -> str:
    names = list(names)
    return f"{names[0]}..{names[-1]} ({len(names)})" if len(names) > 3 else ", ".join(names)


def _write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    import io

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())
