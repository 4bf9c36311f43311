"""MLflow for a streamed run: one run with the config's params, the metrics and the per-stage
seconds, the summary file as an artifact and the log as its dataset input."""

from __future__ import annotations

from pathlib import Path

from pcpg_dist.tracking.connection import _retry
from pcpg_dist.tracking.datasets import log_data_inputs
from pcpg_dist.tracking.logged import _log_metrics, _log_params
from pcpg_dist.tracking.runs import open_experiment
from pcpg_dist.tracking.tags import PARENT_ROLE, ROLE


def log_streamed(
    uri: str | None, cfg, metrics: dict[str, float], summary: Path, data: list, command: str
) -> str:
    """Log a finished streamed run; returns its run id."""
    uri, client, exp_id = open_experiment(cfg.name, uri)
    run = _retry(
        client.create_run,
        exp_id,
        run_name=f"{cfg.name} (streamed)",
        tags={ROLE: PARENT_ROLE, "pcpg.streamed": "true", "pcpg.command": command[:5000]},
    )
    run_id = run.info.run_id
    _log_params(client, run_id, cfg.flat())
    _log_metrics(client, run_id, metrics)
    log_data_inputs(client, run_id, data)
    _retry(client.log_artifact, run_id, str(summary))
    _retry(client.set_terminated, run_id)
    return run_id
