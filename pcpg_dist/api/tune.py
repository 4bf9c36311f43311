"""`pcpg tune` as a call: the study of :mod:`pcpg_dist.orchestration.tuning`, recorded in MLflow
by :class:`~pcpg_dist.tracking.study.StudyTracker` (the api layer composes the two, neither
imports the other)."""

from __future__ import annotations

from pathlib import Path

from pcpg_dist.config import ExperimentConfig
from pcpg_dist.orchestration.tuning import Storage, TuneResult, run_study, trial_task
from pcpg_dist.orchestration.tuning.study import TrialFn
from pcpg_dist.tracking.study import StudyTracker


def tune(
    cfg: ExperimentConfig,
    storage_url: str | Storage | None = None,
    workdir: Path = Path("runs"),
    tracking_uri: str | None = None,
    track: bool = True,
    show_progress: bool = True,
    n_trials: int | None = None,
    study_name: str | None = None,
    out: Path | None = None,
    trial_fn: TrialFn = trial_task,
) -> TuneResult:
    """Run (or resume) the study of ``cfg`` on Ray (initialised already) and, unless ``track`` is
    off, log it to MLflow at ``tracking_uri``: a parent run per study, a child per trial.
    The other arguments are :func:`~pcpg_dist.orchestration.tuning.run_study`'s."""
    return run_study(
        cfg,
        storage_url=storage_url,
        workdir=workdir,
        show_progress=show_progress,
        n_trials=n_trials,
        study_name=study_name,
        out=out,
        trial_fn=trial_fn,
        hooks=StudyTracker(tracking_uri) if track else None,
    )
