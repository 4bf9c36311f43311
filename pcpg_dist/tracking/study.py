"""MLflow record of a `pcpg tune` study: one parent run per study (found again on resume), one
child run per finished trial, logged as trials finish so a crash never loses one.

It observes a study through the calls of
:class:`~pcpg_dist.orchestration.tuning.study.StudyHooks`; everything it logs comes in as
arguments (the Optuna study, the result), so tracking imports nothing of orchestration.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pcpg_dist.config import ExperimentConfig
    from pcpg_dist.orchestration.tuning.study import TuneResult


@dataclass
class StudyTracker:
    """One MLflow parent run per study (found again on resume), one child run per finished trial.

    Built with the tracking URI (None: the default store); :meth:`started` finds or creates the
    parent run."""

    uri: str | None = None
    experiment_id: str = ""
    parent_id: str | None = None
    logged: set[int] = field(default_factory=set)
    inputs: list = field(default_factory=list)  # the study's data, logged on it and every trial

    @property
    def run_id(self) -> str | None:
        """The study's parent run."""
        return self.parent_id

    def started(self, cfg: ExperimentConfig, study_name: str, storage: str, study: Any) -> None:
        """Find the study's parent run (a resumed study) or create it, and the trials it logged."""
        from pcpg_dist.pipeline.declared import input_key
        from pcpg_dist.tracking.connection import _retry
        from pcpg_dist.tracking.datasets import data_inputs, log_data_inputs
        from pcpg_dist.tracking.runs import open_experiment
        from pcpg_dist.tracking.tags import ROLE

        uri, client, exp_id = open_experiment(cfg.name, self.uri)
        found = _retry(
            client.search_runs,
            [exp_id],
            filter_string=f"tags.`{ROLE}` = 'study' and tags.`pcpg.study` = '{study_name}'",
            max_results=1,
        )
        if found:
            parent = found[0].info.run_id
            _retry(client.update_run, parent, status="RUNNING")
        else:
            tags = {
                ROLE: "study",
                "pcpg.study": study_name,
                "pcpg.optuna_storage": storage,
                "mlflow.runName": study_name,
                "pcpg.config_hash": cfg.hash(),
            }
            parent = _retry(client.create_run, exp_id, tags=tags).info.run_id
        children = _retry(
            client.search_runs, [exp_id], filter_string=f"tags.`mlflow.parentRunId` = '{parent}'"
        )
        logged = {int(r.data.tags["pcpg.trial"]) for r in children if "pcpg.trial" in r.data.tags}
        self.uri, self.experiment_id, self.parent_id, self.logged = uri, exp_id, parent, logged
        self.inputs = data_inputs(cfg, input_key(cfg))
        log_data_inputs(client, parent, self.inputs)

    def trials_finished(self, study: Any) -> None:
        """A child run for every finished trial not logged yet (so a crash never loses one)."""
        from optuna.trial import TrialState

        from pcpg_dist.tracking.connection import _client, _retry
        from pcpg_dist.tracking.datasets import log_data_inputs
        from pcpg_dist.tracking.logged import _log_metrics, _log_params
        from pcpg_dist.tracking.tags import ROLE

        client = _client(self.uri)
        for t in study.get_trials(
            deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL)
        ):
            if t.number in self.logged:
                continue
            tags = {
                "mlflow.parentRunId": self.parent_id,
                "mlflow.runName": f"trial-{t.number}",
                ROLE: "trial",
                "pcpg.trial": str(t.number),
                "pcpg.trial_state": t.state.name,
            }
            for attr in ("error", "pruned_reason"):
                if attr in t.user_attrs:
                    tags[f"pcpg.{attr}"] = str(t.user_attrs[attr])[:5000]
            start = int(t.datetime_start.timestamp() * 1000) if t.datetime_start else None
            run_id = _retry(
                client.create_run, self.experiment_id, start_time=start, tags=tags
            ).info.run_id
            _log_params(client, run_id, {**t.user_attrs.get("params_full", {}), **t.params})
            log_data_inputs(client, run_id, self.inputs)
            metrics = {k: v for k, v in t.user_attrs.items() if isinstance(v, float)}
            if t.value is not None:
                metrics["score"] = t.value
            _log_metrics(client, run_id, metrics)
            end = int(t.datetime_complete.timestamp() * 1000) if t.datetime_complete else None
            _retry(
                client.set_terminated,
                run_id,
                "FAILED" if t.state == TrialState.FAIL else "FINISHED",
                end,
            )
            self.logged.add(t.number)

    def finished(self, result: TuneResult) -> None:
        """The best score and parameters and the trial counts on the parent run, the study's
        output folder as its artifacts, and the run ended FINISHED."""
        from pcpg_dist.tracking.connection import _client, _retry
        from pcpg_dist.tracking.logged import _log_metrics

        client = _client(self.uri)
        _log_metrics(
            client,
            self.parent_id,
            {
                "best/score": result.best_value,
                **{f"best/{k}": float(v) for k, v in result.best_params.items()},
                **{f"trials/{k.lower()}": float(v) for k, v in result.n_trials.items()},
            },
        )
        if result.out_dir is not None:
            _retry(client.log_artifacts, self.parent_id, str(result.out_dir), "tuning")
        _retry(client.set_terminated, self.parent_id, "FINISHED")

    def failed(self, status: str = "KILLED") -> None:
        """Mark the study's run ended: KILLED when interrupted, FAILED when no trial completed."""
        from pcpg_dist.tracking.connection import _client, end_quietly

        end_quietly(_client(self.uri), self.parent_id, status)
