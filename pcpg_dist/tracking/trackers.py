"""The trackers the runner and the sweep drive: :class:`Tracker` (a config's parent run, its
environments' children and the agents model), :func:`log_environment` and :class:`SweepTracker`."""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from pcpg_dist.common.point_labels import point_label, short_keys
from pcpg_dist.tracking.connection import (
    _client,
    _retry,
    check_tracking_uri,
    end_quietly,
    writing_to,
)
from pcpg_dist.tracking.datasets import DataInput, data_inputs, log_data_inputs
from pcpg_dist.tracking.logged import (
    _digest,
    _finite,
    _log_folder,
    _log_once,
    _std_table,
    describe_run,
    parent_metrics,
)
from pcpg_dist.tracking.runs import (
    _command,
    _find_or_create,
    _provenance_tags,
    _runs_with,
    killed_if_interrupted,
    open_experiment,
)
from pcpg_dist.tracking.store import default_tracking_uri, prepare_store, store_lock
from pcpg_dist.tracking.tags import (
    AGENTS,
    ARTIFACTS,
    CONFIG_HASH,
    LOGGED,
    NOTE,
    PARENT,
    PARENT_ROLE,
    POINT_ROLE,
    ROLE,
    RUN_NAME,
    SAME_AS,
    SWEEP_KEY,
    SWEEP_ROLE,
    UNIT,
)


@dataclass
class Tracker:
    """The driver's handle on a config's MLflow experiment and parent run."""

    uri: str
    experiment_id: str
    parent_id: str
    config_hash: str
    cfg: object = None
    label: str = ""  # a sweep point's axis values, short ("noise_max=0.3 k=4"): its runs' names
    sweep_point: bool = False  # a point of a sweep: stage timings go on the sweep's run, not here
    inputs: tuple[DataInput, ...] = ()  # the data it used, logged on it and its children

    @staticmethod
    def start(
        cfg,
        uri: str | None,
        out_dir: Path,
        *,
        parent_run_id: str | None = None,
        params: dict[str, str] | None = None,
        ikey: str | None = None,
        units: list | None = None,
    ) -> Tracker:
        """Find or create the config's parent run (keyed by its content hash).

        With ``parent_run_id`` (a sweep) the run is a nested child of that run, in its experiment,
        and ``params`` (the point's overrides, dotted keys) are logged as its params. With
        ``ikey`` (the data's input key) the data is logged as the run's dataset inputs (profiled
        from its evaluation ``units`` where given).
        """
        if parent_run_id:
            uri = uri or default_tracking_uri()
            check_tracking_uri(uri)
            prepare_store(uri)
            client = _client(uri)
            exp_id = _retry(client.get_run, parent_run_id).info.experiment_id
        else:
            uri, client, exp_id = open_experiment(cfg.name, uri)
        chash = cfg.hash()
        shown = " ".join(f"{k}={v}" for k, v in (params or {}).items())
        label = point_label(params or {}) if parent_run_id else ""
        tags = {
            RUN_NAME: label or f"{cfg.name}-{chash[:8]}",
            **_provenance_tags(out_dir),
            NOTE: f"`{cfg.name}`: running (config hash `{chash}`).",
        }
        if params:
            tags["pcpg.overrides"] = shown
        all_params = {**cfg.flat(), **{k: str(v) for k, v in (params or {}).items()}}
        role = POINT_ROLE if parent_run_id else PARENT_ROLE
        legacy = {ROLE: PARENT_ROLE, CONFIG_HASH: chash} if parent_run_id else None
        parent, _ = _find_or_create(
            client,
            uri,
            exp_id,
            {ROLE: role, CONFIG_HASH: chash},
            parent_run_id,
            tags,
            all_params,
            legacy=legacy,
        )
        with killed_if_interrupted(client, parent):  # profiling the data takes a while
            inputs = tuple(data_inputs(cfg, ikey, units)) if ikey else ()
            log_data_inputs(client, parent, list(inputs))
        return Tracker(uri, exp_id, parent, chash, cfg, label, bool(parent_run_id), inputs)

    def env_logged(self, env: str, unit_key: str) -> bool:
        return (env, unit_key) in self.logged_units()

    def logged_units(self) -> set[tuple[str, str]]:
        """(environment, unit key) of every FINISHED environment run under this parent, found
        with one search (a thousand environments are not a thousand queries)."""
        runs = _runs_with(
            _client(self.uri), self.experiment_id, {ROLE: "environment"}, self.parent_id
        )
        return {
            (r.data.tags.get("pcpg.env", ""), r.data.tags.get(UNIT, ""))
            for r in runs
            if r.info.status == "FINISHED"
        }

    def child_info(self, env: str, unit_key: str, cluster_metrics: dict[str, float]) -> dict:
        return {
            "uri": self.uri,
            "experiment_id": self.experiment_id,
            "parent_id": self.parent_id,
            "unit_key": unit_key,
            "config_hash": self.config_hash,
            "cluster_metrics": cluster_metrics,
            "label": self.label,
            "inputs": [i.as_dict() for i in self.inputs],
        }

    def finish(
        self, result, agents_dir: Path | None = None, report_dir: Path | None = None
    ) -> None:
        """Log the headline once: a rerun from cache finds the digest and logs nothing again, and
        of two runs finishing one parent together, the second finds the first's digest."""
        with store_lock(self.uri, f"finish:{self.parent_id}"):
            self._finish(result, agents_dir, report_dir)

    def _finish(self, result, agents_dir: Path | None, report_dir: Path | None) -> None:
        client = _client(self.uri)
        run = _retry(client.get_run, self.parent_id)
        tags = run.data.tags
        points, scales = parent_metrics(result, timings=not self.sweep_point)
        # the results, not the timings: a rerun's summary stage takes its own time, and must not
        # make the run log everything again
        digest = _digest([pt for pt in points if not pt[0].startswith("time/")])
        if tags.get(LOGGED) != digest:
            note = (
                describe_run(self.cfg, result, scales, _command(result.out_dir))
                if self.cfg is not None
                else ""
            )
            _log_once(
                client,
                self.parent_id,
                points,
                {
                    LOGGED: digest,
                    **({NOTE: note} if note else {}),
                    "pcpg.curve_steps": json.dumps(scales),
                },
            )
        summary, report = Path(result.out_dir) / "summary", report_dir
        if tags.get(ARTIFACTS) != digest:
            if summary.is_dir():
                _log_folder(client, self.parent_id, summary, "summary")
                _retry(
                    client.log_text,
                    self.parent_id,
                    _std_table(result.metrics),
                    "summary/metrics.csv",
                )
            if report is not None and report.is_dir():
                _log_folder(client, self.parent_id, report, "report")
            _retry(client.set_tag, self.parent_id, ARTIFACTS, digest)
        if agents_dir is not None and not tags.get(AGENTS):
            self._log_agents(agents_dir)
            _retry(client.set_tag, self.parent_id, AGENTS, "yes")
        if run.info.status != "FINISHED":
            _retry(client.set_terminated, self.parent_id, "FINISHED")

    def _log_agents(self, agents_dir: Path) -> None:
        """The run's agents as one pyfunc model (see :mod:`pcpg_dist.tracking.agent_model`).

        The model's artifacts are ``<env>.npz`` + ``<env>.json`` (the run's torch files
        converted), so serving it needs numpy, pandas and mlflow only, pinned to the versions
        installed here: MLflow resolves and infers nothing while logging. MLflow 3.17 would also
        copy the uv.lock and pyproject.toml of the working directory into the model (torch and
        all, for ``--env-manager uv``) when it finds them; ``MLFLOW_UV_AUTO_DETECT=false`` keeps
        the model's environment to its own requirements. The fluent run is this parent, resumed
        ended by the fluent API (the first time only: ``finish`` skips it once logged).
        """
        import mlflow

        import pcpg_dist.tracking.agent_model as agent_model
        from pcpg_dist.stages.agents_folder import load_run_agents
        from pcpg_dist.tracking import agent_packaging
        from pcpg_dist.tracking.mlflow_quiet import quiet_logging

        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp) / "agents"
            for env, cells in load_run_agents(agents_dir).items():
                agent_packaging.write_env_agents(folder / env, env, cells)
            written = agent_model.read_all(folder)
            mlflow.set_tracking_uri(self.uri)
            before = os.environ.get("MLFLOW_UV_AUTO_DETECT")
            os.environ["MLFLOW_UV_AUTO_DETECT"] = "false"
            try:
                with (
                    writing_to(self.uri),
                    quiet_logging(),
                    mlflow.start_run(run_id=self.parent_id),
                ):
                    mlflow.pyfunc.log_model(
                        name="agents",
                        python_model=agent_model.__file__,
                        artifacts={"agents": str(folder)},
                        signature=agent_packaging.signature(written),
                        input_example=agent_packaging.input_example(written),
                        conda_env=agent_packaging.conda_env(),
                    )
            finally:
                if before is None:
                    os.environ.pop("MLFLOW_UV_AUTO_DETECT", None)
                else:
                    os.environ["MLFLOW_UV_AUTO_DETECT"] = before

    def fail(self) -> None:
        end_quietly(_client(self.uri), self.parent_id)


@dataclass
class SweepTracker:
    """A sweep's MLflow run: the parent of one run per point (:meth:`Tracker.start` with its id)."""

    uri: str
    experiment_id: str
    parent_id: str
    sweep_key: str

    @staticmethod
    def start(
        name: str, sweep_key: str, axes: dict[str, list], description: str, uri: str | None = None
    ) -> SweepTracker:
        """Find (by ``sweep_key``) or create the sweep run in experiment ``name``; idempotent."""
        uri, client, exp_id = open_experiment(name, uri)
        params = {f"sweep.{axis}": ",".join(map(str, values)) for axis, values in axes.items()}
        params["sweep.axes"] = ",".join(axes)
        params["sweep.points"] = str(math.prod(len(v) for v in axes.values()) if axes else 0)
        n = params["sweep.points"]
        tags = {
            RUN_NAME: f"sweep {' x '.join(short_keys(list(axes)).values())} ({n} points) {sweep_key[:8]}",
            NOTE: description,
            **_provenance_tags(),
        }
        run_id, _ = _find_or_create(
            client, uri, exp_id, {ROLE: SWEEP_ROLE, SWEEP_KEY: sweep_key}, None, tags, params
        )
        return SweepTracker(uri, exp_id, run_id, sweep_key)

    def finish(
        self,
        metrics: dict[str, float] | None,
        artifacts: list[Path],
        *,
        best_points: dict[str, str] | None = None,
        timings: dict[str, float] | None = None,
        note: str | None = None,
        inputs: list[DataInput] | None = None,
    ) -> None:
        """Log the sweep's metrics and artifacts once; a rerun with the same results logs nothing.

        ``best_points`` (metric -> the point that has it) become tags ``pcpg.best_point/<metric>``;
        ``note`` replaces the description; ``timings`` (``time/*`` metrics: the stage times of the
        points this call computed, all batched together) are logged with the results but left out
        of the digest, so a rerun that computes nothing logs nothing. ``inputs``: every point's
        data, as the sweep run's dataset inputs.
        """
        client = _client(self.uri)
        log_data_inputs(client, self.parent_id, inputs or [])
        # two sweeps finishing one sweep run: the second finds the first's digest
        with store_lock(self.uri, f"finish:{self.parent_id}"):
            self._finish(client, metrics, artifacts, best_points, timings, note)

    def _finish(self, client, metrics, artifacts, best_points, timings, note) -> None:
        run = _retry(client.get_run, self.parent_id)
        points = [(k, float(v), 0) for k, v in sorted((metrics or {}).items()) if _finite(v)]
        files = sorted(
            (
                Path(a).name,
                hashlib.sha256(Path(a).read_bytes()).hexdigest() if Path(a).is_file() else "",
            )
            for a in artifacts
        )
        tags = {f"pcpg.best_point/{k}": v for k, v in sorted((best_points or {}).items())}
        if note:
            tags[NOTE] = note
        digest = _digest(points, files, tags)
        if run.data.tags.get(LOGGED) != digest:  # metrics and their digest in one batch
            times = [(k, float(v), 0) for k, v in sorted((timings or {}).items()) if _finite(v)]
            _log_once(client, self.parent_id, points + times, {**tags, LOGGED: digest})
        if (
            run.data.tags.get(ARTIFACTS) != digest
        ):  # files are overwritten, never appended: safe to redo
            for a in map(Path, artifacts):
                if a.is_dir():
                    _log_folder(client, self.parent_id, a, a.name)
                elif a.is_file():
                    _retry(client.log_artifact, self.parent_id, str(a))
            _retry(client.set_tag, self.parent_id, ARTIFACTS, digest)
        if run.info.status != "FINISHED":
            _retry(client.set_terminated, self.parent_id, "FINISHED")

    def add_reused(self, point_run_id: str) -> None:
        """List a point this call reused (an earlier sweep, e.g. before an axis was extended, ran
        it and logged it under its own sweep run) under this sweep too: a run of the same name,
        params and metrics (each metric's whole history, so its curves over p), tagged
        ``pcpg.same_as`` with the run it copies; its environments and artifacts stay on that run.
        Nothing when the point's run is already this sweep's child; idempotent."""
        client = _client(self.uri)
        src = _retry(client.get_run, point_run_id)
        if src.data.tags.get(PARENT) == self.parent_id:
            return
        name = src.data.tags.get(RUN_NAME, point_run_id)
        note = (
            f"{name}: reused by this sweep from run `{point_run_id}` of an earlier sweep, which "
            f"computed it; that run holds its environments, figures and agents. Metrics copied."
        )
        run_id, finished = _find_or_create(
            client,
            self.uri,
            self.experiment_id,
            {ROLE: POINT_ROLE, SAME_AS: point_run_id},
            self.parent_id,
            {RUN_NAME: name, NOTE: note},
            dict(src.data.params),
        )
        if finished:
            return
        points = [
            (k, m.value, m.step)
            for k in sorted(src.data.metrics)
            for m in _retry(client.get_metric_history, point_run_id, k)
        ]
        _log_once(client, run_id, points, {})
        _retry(client.set_terminated, run_id, "FINISHED")

    def fail(self) -> None:
        end_quietly(_client(self.uri), self.parent_id)
