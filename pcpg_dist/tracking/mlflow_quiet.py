"""MLflow's chatter silenced while the agents model is logged or loaded (loggers, warnings and
progress bars that say nothing a user could act on), restored afterwards."""

from __future__ import annotations

import contextlib
import logging
import os
import warnings
from collections.abc import Iterator

# INFO and warnings MLflow emits while logging or loading a model whose signature, input example
# and requirements are all given: they say nothing a user could act on.
_CHATTY = (
    "mlflow.pyfunc",
    "mlflow.models",
    "mlflow.models.model",
    "mlflow.models.signature",
    "mlflow.models.utils",
    "mlflow.utils.environment",
    "mlflow.utils.requirements_utils",
    "mlflow.types",
    "mlflow.tracking._model_registry",
    "mlflow.store.artifact",
)


@contextlib.contextmanager
def quiet_logging() -> Iterator[None]:
    """Within the block: MLflow's model-logging loggers at ERROR, its Python warnings ignored, no
    artifact progress bars. Levels and settings are restored afterwards."""
    loggers = [logging.getLogger(n) for n in _CHATTY]
    levels = [lg.level for lg in loggers]
    bar = os.environ.get("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR")
    os.environ["MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR"] = "false"
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", module=r"mlflow(\.|$)")
            yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)
        if bar is None:
            os.environ.pop("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", None)
        else:
            os.environ["MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR"] = bar
