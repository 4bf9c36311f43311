"""`pcpg run`: the whole pipeline for one config, with its outputs and MLflow runs."""

from __future__ import annotations

from pathlib import Path

from pcpg_dist.api.hooks import OutputsAndTracking
from pcpg_dist.config import ExperimentConfig
from pcpg_dist.domains.sources import stream_source
from pcpg_dist.orchestration.executors import Executor
from pcpg_dist.orchestration.points import Point, RunResult
from pcpg_dist.orchestration.runner import run_points
from pcpg_dist.pipeline.checks import check_apart_from_inputs


def run_experiment(
    cfg: ExperimentConfig,
    workdir: Path = Path("runs"),
    tracking_uri: str | None = None,
    track: bool = True,
    show_progress: bool = True,
    command: str = "",
    executor: Executor | None = None,
) -> RunResult:
    """Run (or resume) a whole experiment into ``workdir/<name>``. With the default executor Ray
    must be initialised by the caller; ``LocalExecutor()`` runs every job in this process."""
    out = Path(workdir).resolve() / cfg.name
    check_apart_from_inputs(cfg, out, "--workdir")
    source = stream_source(cfg)
    if source is not None:  # one log too large for one process: ray.data, block by block
        from pcpg_dist.api.streamed import run_streamed

        return run_streamed(cfg, source, out, tracking_uri, track, show_progress, command)
    hooks = OutputsAndTracking(tracking_uri, track, show_progress)
    return run_points(
        [Point(cfg, out, command=command)],
        out / "cache",
        hooks=hooks,
        executor=executor,
        show_progress=show_progress,
    )[0]
