"""``pcpg report RUN`` and ``pcpg reproduce RUN``: what RUN names (a run's or a sweep's folder, an
MLflow run id or an experiment name), downloaded from MLflow when it is not local. Resolving needs
tracking and the result is rendered by reporting, hence this layer above both."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pcpg_dist.common.errors import ConfigError, first_line
from pcpg_dist.reporting.sweep_files import is_sweep_folder


@dataclass(frozen=True)
class Source:
    """What `pcpg report` renders: a run's ``summary`` folder, or a sweep's folder (``sweep.json``,
    ``summary.csv``, figures), and the MLflow run id it came from (``None`` for a local folder)."""

    kind: str  # "run" or "sweep"
    folder: Path
    run_id: str | None = None


def resolve(target: str, tracking_uri: str | None, workdir: Path) -> Source:
    """A local run folder (``runs/NAME`` or its ``summary``), a sweep folder (``runs/NAME/sweep``), an
    MLflow run id (a run, a sweep or one point of a sweep) or an experiment name (its newest
    top-level run: a `pcpg run` or a `pcpg sweep`); MLflow artifacts are downloaded under
    ``workdir/.report-cache/<run id>``."""
    path = Path(target)
    if (path / "run.json").is_file():
        return Source("run", path)
    if (path / "summary" / "run.json").is_file():
        return Source("run", path / "summary")
    if is_sweep_folder(path):
        return Source("sweep", path)
    from pcpg_dist.tracking.runs import find_run

    run, uri = find_run(target, tracking_uri)
    run_id = run.info.run_id
    local = Path(workdir) / ".report-cache" / run_id

    if run.data.tags.get("pcpg.role") == "sweep":  # the sweep's files lie at its run's root
        got = _download(run_id, None, local / "sweep", uri)
        return Source("sweep", Path(got), run_id)
    return Source("run", Path(_download(run_id, "summary", local, uri)), run_id)


def _download(run_id: str, artifact_path: str | None, dst: Path, uri: str) -> str:
    import mlflow.artifacts
    from mlflow.exceptions import MlflowException

    from pcpg_dist.common.errors import ServiceError

    dst.mkdir(parents=True, exist_ok=True)
    try:
        return mlflow.artifacts.download_artifacts(
            run_id=run_id, artifact_path=artifact_path, dst_path=str(dst), tracking_uri=uri
        )
    except (MlflowException, OSError) as e:
        first = first_line(e)
        what = f"no {artifact_path!r} artifacts" if artifact_path else "no artifacts"
        raise ServiceError(
            f"MLflow run {run_id} at {uri} has {what} to report ({first}); is it a pcpg run "
            "that finished?"
        ) from None


def sweep_refusal(target: str, tracking_uri: str | None, command: str) -> None:
    """Raise a one-line :class:`ConfigError` when ``target`` is a whole sweep (its folder, or its MLflow
    run): ``command`` works on one run, so name one of the sweep's points instead."""
    path = Path(target)
    if (
        not (path / "run.json").is_file()
        and not (path / "summary" / "run.json").is_file()
        and is_sweep_folder(path)
    ):
        points = (
            sorted(p.name for p in (path / "points").iterdir() if p.is_dir())
            if (path / "points").is_dir()
            else []
        )
        example = f", e.g. {path / 'points' / points[0]}" if points else ""
        raise ConfigError(
            f"{target} is the folder of a whole pcpg sweep; {command} takes one run: give one of "
            f"its points' folders ({path / 'points'}/<point>{example}) or a point's MLflow run id"
        )
    if path.exists():
        return
    from pcpg_dist.tracking.runs import find_run, sweep_points_of

    run, uri = find_run(target, tracking_uri)
    if run.data.tags.get("pcpg.role") != "sweep":
        return
    points = sweep_points_of(run.info.run_id, uri)
    example = f", e.g. {points[0].info.run_id} ({points[0].info.run_name})" if points else ""
    raise ConfigError(
        f"{target} is the MLflow run of a whole pcpg sweep ({run.info.run_name}); {command} takes "
        f"one run: give one of the sweep's point runs{example} or a point's folder "
        "(<workdir>/<name>/sweep/points/<point>)"
    )


def resolve_summary(
    target: str, tracking_uri: str | None, workdir: Path, command: str = "pcpg reproduce"
) -> tuple[Path, str | None]:
    """The ``summary`` folder of one run (see :func:`resolve`); a whole sweep is refused in one line."""
    sweep_refusal(target, tracking_uri, command)
    source = resolve(target, tracking_uri, workdir)
    return source.folder, source.run_id
