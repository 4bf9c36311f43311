"""An environment's child run under its point's parent run: metrics, tables, figures, models.
Logged by tasks on the driver's machine, a share of a run's environments each."""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

from pcpg_dist.tracking.connection import _client, _retry
from pcpg_dist.tracking.datasets import log_data_inputs
from pcpg_dist.tracking.logged import (
    _confidence_tag,
    _copy_without_bookkeeping,
    _digest,
    _log_once,
    _std_table,
    child_metrics,
)
from pcpg_dist.tracking.runs import _runs_with
from pcpg_dist.tracking.store import store_lock
from pcpg_dist.tracking.tags import CONFIG_HASH, LOGGED, NOTE, PARENT, ROLE, RUN_NAME, UNIT


def log_environments(jobs: list[tuple[dict, str, str, dict[str, float], list[str]]]) -> list[str]:
    """:func:`log_environment` for each job (its arguments) in turn; the run ids. One Ray task
    logs a share of a run's environments on the driver's node, where their files are."""
    return [log_environment(*job) for job in jobs]


def log_environment(
    info: dict, env: str, out_dir: str, metrics: dict[str, float], model_paths: list[str]
) -> str:
    """One environment's child run: metrics (curves over p and c), tables, figures, models.

    Runs in any process on the machine that holds ``out_dir`` and the models. Under the (parent,
    environment) lock: a FINISHED child with the same unit key is kept and nothing is logged; any
    other child of that environment (a half-written one of a killed run, or one from other
    settings) is deleted first. Params, metrics and tags go in as few batches as MLflow allows,
    the files in one upload.
    """
    uri, parent = info["uri"], info["parent_id"]
    client = _client(uri)
    with store_lock(uri, f"child:{parent}:{env}"):
        runs = _runs_with(client, info["experiment_id"], {"pcpg.env": env}, parent)
        # a sweep point's environments are named with the point: every point has an E1
        name = f"{env} · {info['label']}" if info.get("label") else env
        for run in runs:
            if run.info.status == "FINISHED" and run.data.tags.get(UNIT) == info["unit_key"]:
                if run.data.tags.get(RUN_NAME) != name:  # named by an older pcpg
                    _retry(client.set_tag, run.info.run_id, RUN_NAME, name)
                return run.info.run_id
        for run in runs:
            _retry(client.delete_run, run.info.run_id)
        merged = {**info["cluster_metrics"], **metrics}
        points, scales = child_metrics(merged)
        tags = {
            PARENT: parent,
            RUN_NAME: name,
            "pcpg.env": env,
            UNIT: info["unit_key"],
            ROLE: "environment",
            CONFIG_HASH: info["config_hash"],
            **_confidence_tag(merged),
            NOTE: f"Environment `{env}`: its evaluation tables and figures (`evaluation/`), trained "
            f"cells (`models/`), curves over p and c (steps: {json.dumps(scales)}), std over seeds "
            f"in `evaluation/metrics.csv`.",
        }
        run_id = _retry(client.create_run, info["experiment_id"], tags=tags).info.run_id
        log_data_inputs(client, run_id, info.get("inputs", []))
        _log_once(client, run_id, points, {LOGGED: _digest(points)}, params={"env": env})
        with tempfile.TemporaryDirectory() as tmp:  # every file in one upload
            root = Path(tmp)
            _copy_without_bookkeeping(Path(out_dir), root / "evaluation")
            (root / "evaluation" / "metrics.csv").write_text(_std_table(merged))
            for path in model_paths:
                p = Path(path)
                for f in (p, p.with_suffix(".json")):
                    if f.is_file():
                        (root / "models" / p.parent.name).mkdir(parents=True, exist_ok=True)
                        shutil.copyfile(f, root / "models" / p.parent.name / f.name)
            _retry(client.log_artifacts, run_id, str(root))
        _retry(client.set_terminated, run_id, "FINISHED")
        return run_id
