"""Reading the agents a run wrote (``<env>/groupNNN.pt|.json`` under its ``agents`` folder).

Kept below tracking and reporting so both use the same checked reader: tracking converts these
files into the MLflow agents model, the ONNX export reads them (and, through the api layer, the
MLflow model's own ``<env>.npz`` layout too).
"""

from __future__ import annotations

from pathlib import Path

from pcpg_dist.common.errors import DataError


def read_run_layout(folder: Path) -> dict:
    """``{env: TrainedCells}`` of a run's agents folder (``<env>/*.pt``), possibly empty.

    The folder is checked against the run's ``index.json`` and summary
    (:func:`~pcpg_dist.common.run_folders.check_run_agents`), every file against its JSON
    (:func:`~pcpg_dist.stages.bc.check_cells`), and every env name must be a plain name, since it
    becomes a file name: a DataError naming the file otherwise.
    """
    from pcpg_dist.common.files import confined
    from pcpg_dist.common.inputs import entries, input_file
    from pcpg_dist.common.run_folders import check_run_agents
    from pcpg_dist.stages.bc import TrainedCells

    folder = Path(folder)
    check_run_agents(folder)  # a run's agents: the files it wrote, for the environments it reports
    out = {}
    # the input policy (common.inputs): links only within the folder, no special files
    for env_dir in entries(folder, "agents folder", dirs=True):
        groups = entries(env_dir, "agent file", suffixes=[".pt"])
        if groups:
            confined(folder, env_dir.name, f"{env_dir}: env folder")
            parts = []
            for g in groups:
                input_file(g.with_suffix(".json"), "agent file", folder=env_dir)
                parts.append(TrainedCells.load(g))  # checked against its JSON (check_cells)
            out[env_dir.name] = TrainedCells.concat(parts)
    return out


def require_agents(folder: Path, found: dict) -> dict:
    """``found`` itself, or the one-line DataError of a folder that holds no trained agents."""
    if not found:
        raise DataError(
            f"{folder}: no trained agents (expected <env>/*.pt from pcpg run, "
            f"or <env>.npz from the MLflow agents model)"
        )
    return found


def load_run_agents(folder: Path) -> dict:
    """``{env: TrainedCells}`` of a run's agents folder; a DataError when it holds none."""
    return require_agents(Path(folder), read_run_layout(folder))
