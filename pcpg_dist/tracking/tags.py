"""The tags, roles and limits every tracking module agrees on: the names pcpg gives its MLflow
tags and the batch sizes MLflow accepts (kept apart so no module needs another just for a name)."""

from __future__ import annotations

ROLE, UNIT, CONFIG_HASH = "pcpg.role", "pcpg.unit_key", "pcpg.config_hash"
SWEEP_KEY, LOGGED, ARTIFACTS, AGENTS = (
    "pcpg.sweep_key",
    "pcpg.logged",
    "pcpg.artifacts_logged",
    "pcpg.agents_logged",
)
NOTE, PARENT, RUN_NAME = "mlflow.note.content", "mlflow.parentRunId", "mlflow.runName"
SAME_AS = "pcpg.same_as"  # a sweep's copy of a point another sweep ran (SweepTracker.add_reused)
# The MLflow 3 UI opens an experiment without this tag on its GenAI overview; the classic-ML
# value (mlflow/server/js: ExperimentKind.CUSTOM_MODEL_DEVELOPMENT) opens it on the runs table.
EXPERIMENT_KIND = ("mlflow.experimentKind", "custom_model_development")
MAX_PARENT_METRICS = 30
# Roles (tag ``pcpg.role``): a `pcpg run`'s run is the "parent" of its environments' runs; a `pcpg
# sweep`'s run ("sweep") is the parent of one "point" run per point, each the parent of its
# environments' runs. Points made before the role existed carry "parent" and are retagged when found.
PARENT_ROLE, POINT_ROLE, SWEEP_ROLE = "parent", "point", "sweep"
PARAM_BATCH, METRIC_BATCH = 100, 1000  # MLflow's limits per log_batch call
BOOKKEEPING = ("done.json", "*.lock", "*.tmp", ".*")  # cache bookkeeping, never an artifact
