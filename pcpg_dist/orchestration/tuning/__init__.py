"""`pcpg tune`: choose k and the network sizes with Optuna, one Ray task per trial.

Why this shape:

- **The objective uses no true labels** (:mod:`.objective`). A trial clusters one (or a few)
  environments, trains the PCPG agents and scores their teacher-forced accuracy on held-out
  trajectories, minus a penalty per extra cluster. The gain over No Clustering is logged beside
  it but is not the objective: it would reward *small* BC networks, which No Clustering cannot
  fit a mixture with (see docs/tuning.md).
- **Ask/tell from the driver** (:mod:`.trials`, :mod:`.study`). The driver keeps
  ``parallel_trials`` Ray tasks in flight and tells Optuna each result as it arrives; whoever runs
  the study may observe it through :class:`~.study.StudyHooks` (`pcpg tune` logs every finished
  trial as an MLflow child run of one study parent run, :mod:`pcpg_dist.api.tune`).
- **Storage** (:mod:`.storage`): a journal file for one machine, an RDB with heartbeats for a team.

Modules: space (what is searched), objective (one trial), storage, trials (the ask/tell loop),
study (run_study), outputs (best config, trials table, figure), journal (the checked journal file).
"""

from pcpg_dist.config.stages import MAX_COUNT, PARAMS, TARGETS, TuneConfig
from pcpg_dist.orchestration.tuning.objective import score_trial, trial_task
from pcpg_dist.orchestration.tuning.outputs import best_config_data, write_outputs
from pcpg_dist.orchestration.tuning.space import (
    apply_params,
    objective_key,
    searched_space,
    suggest,
    trial_environments,
    tune_settings,
)
from pcpg_dist.orchestration.tuning.storage import (
    DEFAULT_STORAGE,
    Storage,
    fail_stale,
    open_storage,
    rdb_url,
    state_counts,
)
from pcpg_dist.orchestration.tuning.study import StudyHooks, TuneResult, run_study, study_folder

__all__ = [
    "DEFAULT_STORAGE",
    "MAX_COUNT",
    "PARAMS",
    "TARGETS",
    "Storage",
    "StudyHooks",
    "TuneConfig",
    "TuneResult",
    "apply_params",
    "best_config_data",
    "fail_stale",
    "objective_key",
    "open_storage",
    "rdb_url",
    "run_study",
    "score_trial",
    "searched_space",
    "state_counts",
    "study_folder",
    "suggest",
    "trial_environments",
    "trial_task",
    "tune_settings",
    "write_outputs",
]
