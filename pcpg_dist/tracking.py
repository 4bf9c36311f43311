"""MLflow tracking: one experiment per config name, one parent run per sweep, child runs per environment.

Embedded default: ``sqlite:///<cwd>/mlflow.db`` with artifacts in ``<cwd>/mlruns``, created by the
driver before any worker logs. For a team: ``MLFLOW_TRACKING_URI=http://host:5000`` (an
``mlflow server`` on PostgreSQL with proxied artifacts, see tracking/README.md).

Workers log with :class:`mlflow.MlflowClient` and the parent's run id, never the fluent API (Ray
reuses worker processes). Runs carry ``pcpg.unit_key`` tags, so a rerun finds what is already
logged: a sweep resumes its own parent run and never duplicates a finished child; a child left
half-written by a killed process is deleted and logged again.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import time
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path

import pcpg_dist
from pcpg_dist.errors import ServiceError
from pcpg_dist.provenance import git_commit, uv_lock_hash

# Progress bars of artifact transfers would interleave with ours in the terminal.
os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")

ROLE, UNIT, CONFIG_HASH = "pcpg.role", "pcpg.unit_key", "pcpg.config_hash"
PARAM_BATCH = 100  # MLflow's limit of params per log_batch call


def default_tracking_uri() -> str:
    env = os.environ.get("MLFLOW_TRACKING_URI")
    if env:
        return env
    return f"sqlite:///{Path.cwd().resolve() / 'mlflow.db'}"


def check_reachable(uri: str, timeout: float = 8.0) -> None:
    """Fail fast (within ``timeout`` s) with the URI in the message when a server is down."""
    if not uri.startswith(("http://", "https://")):
        return
    try:
        with urllib.request.urlopen(uri.rstrip("/") + "/health", timeout=timeout) as resp:
            if resp.status != 200:
                raise ServiceError(f"MLflow server at {uri} answered {resp.status} on /health")
    except (urllib.error.URLError, OSError, TimeoutError) as e:
        reason = getattr(e, "reason", e)
        raise ServiceError(f"MLflow tracking server {uri} is unreachable ({reason}); start it or set "
                           f"MLFLOW_TRACKING_URI to a reachable server (unset = local sqlite)") from None


def _client(uri: str):
    from mlflow import MlflowClient

    return MlflowClient(tracking_uri=uri)


def _retry(fn, *args, attempts: int = 5, **kwargs):
    """Call an MLflow client method, retrying transient failures with exponential backoff.

    When the attempts run out the failure becomes a one-line :class:`ServiceError` naming the
    server (the CLI prints it and exits 2): the local results are already written, and rerunning
    the same command logs them without recomputing anything.
    """
    from mlflow.exceptions import MlflowException

    for i in range(attempts):
        try:
            return fn(*args, **kwargs)
        except (MlflowException, OSError) as e:
            if getattr(e, "error_code", "") in ("INVALID_PARAMETER_VALUE", "RESOURCE_ALREADY_EXISTS"):
                raise
            if i == attempts - 1:
                uri = getattr(getattr(fn, "__self__", None), "tracking_uri", "(unknown URI)")
                first = (str(e).strip().splitlines() or [type(e).__name__])[0][:300]
                raise ServiceError(f"MLflow tracking server {uri} failed ({first}); local results are kept: "
                                   f"rerun the same command once it is reachable to log them") from None
            time.sleep(min(2 ** i, 10))
    return None


def _log_params(client, run_id: str, params: dict[str, str]) -> None:
    from mlflow.entities import Param

    items = [Param(k, str(v)[:6000]) for k, v in sorted(params.items())]
    for i in range(0, len(items), PARAM_BATCH):
        _retry(client.log_batch, run_id, params=items[i: i + PARAM_BATCH])


def _log_metrics(client, run_id: str, metrics: dict[str, float]) -> None:
    from mlflow.entities import Metric

    now = int(time.time() * 1000)
    items = [Metric(k, float(v), now, 0) for k, v in sorted(metrics.items())]
    for i in range(0, len(items), 1000):
        _retry(client.log_batch, run_id, metrics=items[i: i + 1000])


def find_sweep_run(target: str, uri: str):
    """An MLflow run id, or an experiment name (its newest pcpg sweep), as the MLflow run."""
    from mlflow.exceptions import MlflowException

    client = _client(uri)
    try:
        return client.get_run(target)
    except MlflowException:
        exp = client.get_experiment_by_name(target)
        if exp is None:
            raise ServiceError(f"{target!r} is neither a run's output folder, an MLflow run id nor an "
                               f"experiment name at {uri}") from None
        runs = _retry(client.search_runs, [exp.experiment_id], filter_string=f"tags.`{ROLE}` = 'parent'",
                      order_by=["attributes.start_time DESC"], max_results=1)
        if not runs:
            raise ServiceError(f"experiment {target!r} at {uri} has no pcpg sweep yet") from None
        return runs[0]


def open_experiment(name: str, uri: str | None):
    """Check the server, then get or create the experiment; returns (uri, client, experiment id).

    On SQLite the artifacts go to ``mlruns/`` beside the database, as an absolute URI, so Ray
    workers log to the same place whatever their working directory.
    """
    uri = uri or default_tracking_uri()
    check_reachable(uri)
    client = _client(uri)
    exp = _retry(client.get_experiment_by_name, name)
    if exp is not None:
        return uri, client, exp.experiment_id
    location = None
    if uri.startswith("sqlite:"):
        location = (Path(uri.removeprefix("sqlite:///")).parent / "mlruns").resolve().as_uri()
    return uri, client, _retry(client.create_experiment, name, artifact_location=location)


@dataclass
class Tracker:
    """The driver's handle on a sweep's MLflow experiment and parent run."""

    uri: str
    experiment_id: str
    parent_id: str
    config_hash: str

    @staticmethod
    def start(cfg, uri: str | None, out_dir: Path) -> Tracker:
        uri, client, exp_id = open_experiment(cfg.name, uri)
        chash = cfg.hash()
        found = _retry(client.search_runs, [exp_id],
                       filter_string=f"tags.`{ROLE}` = 'parent' and tags.`{CONFIG_HASH}` = '{chash}'",
                       order_by=["attributes.start_time DESC"], max_results=1)
        if found:
            parent = found[0].info.run_id
            if found[0].info.status != "FINISHED":
                _retry(client.update_run, parent, status="RUNNING")
        else:
            tags = {ROLE: "parent", CONFIG_HASH: chash, "mlflow.runName": f"{cfg.name}-{chash[:8]}",
                    "pcpg.git_commit": git_commit(), "pcpg.version": pcpg_dist.__version__,
                    "pcpg.uv_lock": uv_lock_hash(), "pcpg.output_dir": str(out_dir)}
            parent = _retry(client.create_run, exp_id, tags=tags).info.run_id
            _log_params(client, parent, cfg.flat())
        return Tracker(uri, exp_id, parent, chash)

    def _children(self, env: str) -> list:
        client = _client(self.uri)
        return _retry(client.search_runs, [self.experiment_id],
                      filter_string=f"tags.`mlflow.parentRunId` = '{self.parent_id}' and tags.`pcpg.env` = '{env}'")

    def env_logged(self, env: str, unit_key: str) -> bool:
        return any(r.info.status == "FINISHED" and r.data.tags.get(UNIT) == unit_key for r in self._children(env))

    def child_info(self, env: str, unit_key: str, cluster_metrics: dict[str, float]) -> dict:
        return {"uri": self.uri, "experiment_id": self.experiment_id, "parent_id": self.parent_id,
                "unit_key": unit_key, "config_hash": self.config_hash, "cluster_metrics": cluster_metrics}

    def finish(self, result, agents_dir: Path | None = None, report_dir: Path | None = None) -> None:
        client = _client(self.uri)
        metrics = {k: v for k, v in result.metrics.items() if v == v}  # drop NaN
        metrics.update({f"time/{k}_seconds": v for k, v in result.stage_seconds.items()})
        _log_metrics(client, self.parent_id, metrics)
        summary = Path(result.out_dir) / "summary"
        if summary.is_dir():
            _retry(client.log_artifacts, self.parent_id, str(summary), "summary")
        if report_dir is not None and report_dir.is_dir():
            _retry(client.log_artifacts, self.parent_id, str(report_dir), "report")
        if agents_dir is not None and not self._has_agents(client):
            self._log_agents(agents_dir)
        _retry(client.set_terminated, self.parent_id, "FINISHED")

    def _has_agents(self, client) -> bool:
        return any(a.path == "agents_logged" for a in _retry(client.list_artifacts, self.parent_id))

    def _log_agents(self, agents_dir: Path) -> None:
        """The sweep's agents as one pyfunc model (driver only: log_model needs the fluent API).

        The model's artifacts are ``<env>.npz`` + ``<env>.json`` (the run's torch files
        converted), so serving it needs numpy, pandas and mlflow only, pinned to the versions
        installed here: MLflow resolves and infers nothing while logging. MLflow 3.17 would also
        copy the uv.lock and pyproject.toml of the working directory into the model (torch and
        all, for ``--env-manager uv``) when it finds them; ``MLFLOW_UV_AUTO_DETECT=false`` keeps
        the model's environment to its own requirements.
        """
        import mlflow

        import pcpg_dist.agent_model as agent_model
        from pcpg_dist.onnx_export import load_agents_folder

        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp) / "agents"
            for env, cells in load_agents_folder(agents_dir).items():
                agent_model.write_env_agents(folder / env, env, cells)
            written = agent_model.read_all(folder)
            mlflow.set_tracking_uri(self.uri)
            before = os.environ.get("MLFLOW_UV_AUTO_DETECT")
            os.environ["MLFLOW_UV_AUTO_DETECT"] = "false"
            try:
                with mlflow.start_run(run_id=self.parent_id):
                    mlflow.pyfunc.log_model(
                        name="agents", python_model=agent_model.__file__, artifacts={"agents": str(folder)},
                        signature=agent_model.signature(written),
                        input_example=agent_model.input_example(written), conda_env=agent_model.conda_env())
                    mlflow.log_text("yes", "agents_logged")
            finally:
                if before is None:
                    os.environ.pop("MLFLOW_UV_AUTO_DETECT", None)
                else:
                    os.environ["MLFLOW_UV_AUTO_DETECT"] = before

    def fail(self) -> None:
        with contextlib.suppress(Exception):  # best effort while already failing
            _retry(_client(self.uri).set_terminated, self.parent_id, "KILLED", attempts=2)


def log_environment(info: dict, env: str, out_dir: str, metrics: dict[str, float],
                    model_paths: list[str]) -> str:
    """Worker side: one child run for an environment's results, tables, figures and models."""
    client = _client(info["uri"])
    stale = _retry(client.search_runs, [info["experiment_id"]],
                   filter_string=f"tags.`mlflow.parentRunId` = '{info['parent_id']}' and tags.`pcpg.env` = '{env}'")
    for run in stale:  # a half-written child of a killed run, or one from other settings
        _retry(client.delete_run, run.info.run_id)
    tags = {"mlflow.parentRunId": info["parent_id"], "mlflow.runName": env, "pcpg.env": env,
            UNIT: info["unit_key"], ROLE: "environment", CONFIG_HASH: info["config_hash"]}
    run_id = _retry(client.create_run, info["experiment_id"], tags=tags).info.run_id
    _log_params(client, run_id, {"env": env})
    _log_metrics(client, run_id, {**info["cluster_metrics"], **metrics})
    _retry(client.log_artifacts, run_id, out_dir, "evaluation")
    for path in model_paths:
        p = Path(path)
        for f in (p, p.with_suffix(".json")):
            if f.is_file():
                _retry(client.log_artifact, run_id, str(f), f"models/{p.parent.name}")
    _retry(client.set_terminated, run_id, "FINISHED")
    return run_id
