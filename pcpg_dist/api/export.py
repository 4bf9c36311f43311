"""``pcpg export onnx RUN``: find a run's agents (its output folder, or an MLflow run by id or
experiment name, downloaded), read them in either layout, and write them as ONNX
(:mod:`pcpg_dist.reporting.onnx_export`). Resolving a run needs tracking and writing needs
reporting, hence this layer above both.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from pcpg_dist.common.errors import DataError, ServiceError, first_line
from pcpg_dist.common.inputs import entries, input_file
from pcpg_dist.reporting.onnx_export import export_onnx
from pcpg_dist.stages.agents_folder import read_run_layout, require_agents


def load_agents_folder(folder: Path) -> dict:
    """``{env: TrainedCells}`` from an agents folder.

    Two layouts: a run's output (``<env>/groupNNN.pt|.json``, written by ``pcpg run``) and the
    MLflow ``agents`` model's artifacts (``<env>.npz|.json``, see :mod:`pcpg_dist.tracking.agent_model`).
    Every file is checked (:func:`check_cells`), a run's against its ``index.json`` and summary
    (:func:`~pcpg_dist.common.run_folders.check_run_agents`), and every env name must be a plain name, since it becomes a file name: a DataError
    naming the file otherwise.
    """
    folder = Path(folder)
    out = read_run_layout(folder)
    npz = entries(folder, "agents model file", suffixes=[".npz"])
    if npz:
        _read_model_layout(folder, npz, out)
    return require_agents(folder, out)


def _read_model_layout(folder: Path, npz: list[Path], out: dict) -> None:
    """Add to ``out`` the environments of the MLflow agents model's ``<env>.npz|.json`` files."""
    from pcpg_dist.common.files import confined
    from pcpg_dist.stages.bc import TrainedCells, check_cells
    from pcpg_dist.stages.ranking import CellSpec
    from pcpg_dist.tracking import agent_model

    for path in npz:
        source = input_file(path.with_suffix(".json"), "agents model file", folder=folder)
        try:
            env = agent_model.read_env_agents(path)
        except agent_model.AgentFileError as e:
            raise DataError(str(e)) from None
        confined(folder, env.env, f"{source}: env")
        if env.env != path.stem:
            raise DataError(
                f"{source}: env {env.env!r} does not match the file's name "
                f"(expected {path.stem!r}, as in {path.name})"
            )
        if env.env in out:
            raise DataError(f"{source}: env {env.env!r} is also in {folder / env.env}/; keep one")
        specs = tuple(CellSpec(s.key, s.kind, s.k, s.p, s.seed, s.c) for s in env.specs)
        cells = TrainedCells(
            specs,
            env.sizes,
            env.activation,
            env.params,
            env.mean,
            env.std,
            np.zeros(len(specs), np.float32),
        )
        check_cells(source, cells)
        out[env.env] = cells


def resolve_agents(target: str, tracking_uri: str | None, workdir: Path) -> Path:
    """The agents folder of RUN: a run's output folder, an MLflow run id or an experiment name
    (its newest top-level run)."""
    from pcpg_dist.api.report import sweep_refusal

    path = Path(target)
    if (path / "agents").is_dir():
        return path / "agents"
    sweep_refusal(
        target, tracking_uri, "pcpg export onnx"
    )  # a whole sweep has no one set of agents
    if path.is_dir() and any(path.glob("*/*.pt")):
        return path
    if path.exists():
        raise DataError(
            f"{path}: no trained agents here (expected {path}/agents/<env>/*.pt, "
            f"written by pcpg run)"
        )
    from mlflow.exceptions import MlflowException

    from pcpg_dist.tracking.runs import find_run

    run, uri = find_run(target, tracking_uri)
    run_id = run.data.tags.get("mlflow.parentRunId", run.info.run_id)  # an environment's child run
    import mlflow.artifacts

    local = Path(workdir) / ".export-cache" / run_id
    try:
        got = mlflow.artifacts.download_artifacts(
            artifact_uri=f"runs:/{run_id}/agents", dst_path=str(local), tracking_uri=uri
        )
    except (MlflowException, OSError) as e:
        raise ServiceError(f"run {run_id} at {uri} has no agents model ({first_line(e)})") from None
    folder = Path(got) / "artifacts" / "agents"
    if not folder.is_dir():
        raise DataError(f"run {run_id}: the agents model has no artifacts/agents folder")
    return folder


def cli_export_onnx(args: argparse.Namespace) -> None:
    """``pcpg export onnx RUN --out DIR``."""
    from pcpg_dist.common.run_folders import check_outside_run

    check_outside_run(Path(args.out))
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(args.workdir) if args.workdir else Path(tmp)
        folder = resolve_agents(args.run, args.tracking_uri, workdir)
        ensembles = load_agents_folder(folder)
        for path in export_onnx(ensembles, Path(args.out)):
            extra = ""
            if path.suffix == ".onnx":
                cells = ensembles[path.stem.removeprefix("agents_")]
                extra = (
                    f"  ({len(cells.specs)} cells, state {cells.state_dim}, "
                    f"{cells.n_actions} actions)"
                )
            print(f"wrote {path}{extra}")
