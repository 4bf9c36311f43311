"""What the agents model is logged with (used by the tracker, never while serving): the run's
cells written as ``<env>.npz`` + ``<env>.json``, the model's signature, input example and pinned
environment (:mod:`pcpg_dist.tracking.agent_model` is the served model itself)."""

from __future__ import annotations

import importlib.metadata
import json
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from pcpg_dist.tracking.agent_model import NC_STYLE, REQUIREMENTS, CellInfo, EnvAgents


def write_env_agents(path: str | Path, env: str, cells) -> Path:
    """``path.npz`` (the arrays) + ``path.json`` (cells, sizes) from a ``TrainedCells``."""
    path = Path(path).with_suffix("")
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {
        **{n: np.ascontiguousarray(v, np.float32) for n, v in cells.params.items()},
        "mean": np.asarray(cells.mean, np.float32),
        "std": np.asarray(cells.std, np.float32),
    }
    np.savez(path.with_suffix(".npz"), **arrays)
    meta = {
        "format": 1,
        "env": env,
        "sizes": list(cells.sizes),
        "activation": cells.activation,
        "specs": [asdict(CellInfo(s.key, s.kind, s.k, s.p, s.seed, s.c)) for s in cells.specs],
    }
    path.with_suffix(".json").write_text(json.dumps(meta, indent=1))
    return path.with_suffix(".npz")


def signature(agents: dict[str, EnvAgents]):
    """Column names and types. Every column is optional to MLflow so that a missing one reaches
    :meth:`PcpgAgents.predict` and gets its one-line error; ``style``, ``seed`` and ``valid`` are
    ``Any`` because MLflow 3.17's enforcement would turn a style of 1.5 into 1, a NaN inside a
    ``valid`` list into True, and fail on a batch where only some rows give a seed."""
    from mlflow.models import ModelSignature
    from mlflow.types import ColSpec, Schema
    from mlflow.types.schema import AnyType

    d = max(a.state_dim for a in agents.values())
    inputs = [
        ColSpec("string", "env", required=False),
        ColSpec(AnyType(), "style", required=False),
        ColSpec("double", "p", required=False),
        ColSpec(AnyType(), "seed", required=False),
        ColSpec(AnyType(), "valid", required=False),
        *(ColSpec("double", f"s{j}", required=False) for j in range(d)),
    ]
    return ModelSignature(inputs=Schema(inputs), outputs=Schema([ColSpec("long", "action")]))


def input_example(agents: dict[str, EnvAgents]) -> pd.DataFrame:
    """One row per environment with a style and p that are trained and a mid-range state."""
    d = max(a.state_dim for a in agents.values())
    rows = []
    for env, a in sorted(agents.items()):
        spec = next(
            (s for s in a.specs if s.kind == "pcpg"), next(s for s in a.specs if s.kind == "nc")
        )
        i = a.specs.index(spec)
        row = {
            "env": env,
            "style": spec.k if spec.kind == "pcpg" else NC_STYLE,
            "p": spec.p,
            "seed": spec.seed,
            "valid": [True] * a.n_actions,
        }
        row.update(
            {f"s{j}": round(float(a.mean[i][j]), 3) if j < a.state_dim else None for j in range(d)}
        )
        rows.append(row)
    return pd.DataFrame(rows)


def pip_requirements() -> list[str]:
    """Exact versions of what this file imports, so MLflow infers nothing when logging."""
    return [f"{name}=={importlib.metadata.version(name)}" for name in REQUIREMENTS]


def conda_env() -> dict:
    """The model's environment, given whole: MLflow then neither infers requirements nor looks
    up a pip version (``pip`` is absent from a uv environment and MLflow warns about it)."""
    python = ".".join(map(str, sys.version_info[:3]))
    return {
        "name": "pcpg-agents",
        "channels": ["conda-forge"],
        "dependencies": [f"python={python}", "pip", {"pip": pip_requirements()}],
    }
