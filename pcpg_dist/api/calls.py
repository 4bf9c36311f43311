"""pcpg from Python (a notebook, a script): the commands as functions, with the same validation
and one-line errors as the CLI, raised as :class:`~pcpg_dist.common.errors.PcpgError` (never
``SystemExit``). Nothing heavy is imported until a function is called."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pcpg_dist.config import ExperimentConfig


def config_of(config: str | Path | dict | ExperimentConfig, overrides: list[str] | None = None):
    """A validated config from a YAML path, a mapping or a config, ``key=value`` overrides applied."""
    from pcpg_dist.config.experiment import parse_config
    from pcpg_dist.config.overrides import apply_overrides, load_config_with, parse_overrides

    if isinstance(config, str | Path):
        return load_config_with(config, overrides)
    raw = config.model_dump(mode="json") if isinstance(config, ExperimentConfig) else dict(config)
    return parse_config(apply_overrides(raw, parse_overrides(overrides or [])), source="<python>")


def run(
    config: str | Path | dict | ExperimentConfig,
    overrides: list[str] | None = None,
    *,
    workdir: str | Path = "runs",
    tracking_uri: str | None = None,
    track: bool = True,
    show_progress: bool = True,
    in_process: bool = False,
) -> Any:
    """`pcpg run` from Python; returns its :class:`~pcpg_dist.orchestration.points.RunResult`.

    Ray starts privately on first use (or joins ``RAY_ADDRESS``); ``in_process=True`` runs every
    job in this process instead, with no Ray at all."""
    from pcpg_dist.api.run import run_experiment

    cfg = config_of(config, overrides)
    return run_experiment(
        cfg,
        workdir=Path(workdir),
        tracking_uri=tracking_uri,
        track=track,
        show_progress=show_progress,
        executor=_executor(in_process),
    )


def cluster(
    config: str | Path | dict | ExperimentConfig,
    out: str | Path,
    overrides: list[str] | None = None,
    *,
    data: str | Path | None = None,
    show_progress: bool = True,
    in_process: bool = False,
) -> dict[str, dict]:
    """`pcpg cluster` from Python: each environment's labels, margins and metrics."""
    from pcpg_dist.api.cluster import cluster as cluster_units

    cfg = config_of(config, overrides)
    executor = _executor(in_process)
    return cluster_units(cfg, Path(out), Path(data) if data else None, show_progress, executor)


def _executor(in_process: bool):
    """This process for every job, or Ray (started privately on first use, or RAY_ADDRESS)."""
    from pcpg_dist.orchestration.executors import LocalExecutor, RayExecutor

    if in_process:
        return LocalExecutor()
    from pcpg_dist.orchestration.ray_pool import init_ray

    init_ray()
    return RayExecutor()
