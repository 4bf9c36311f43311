"""The ``trajectories`` config section (a user's own play logs) and the Minari dataset ids it
accepts. Pydantic only, so the registry can read it when a config is loaded without importing the
table readers.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, Field, PrivateAttr, ValidationInfo, field_validator

from pcpg_dist.config.checks import relative_to_config
from pcpg_dist.config.schema import StrictModel

#: a Minari dataset id, ``[namespace/]name[-vN]`` (Minari's own grammar; a namespace may hold '/'):
#: never a path
MINARI_ID = re.compile(
    r"^(?:(?P<namespace>[-_\w][-_\w/]*[-_\w]+)/)?(?P<name>[-_\w]+?)(?:-v(?P<version>\d+))?$"
)


def minari_id_problem(dataset_id: object, need_version: bool = False) -> str | None:
    """Why ``dataset_id`` is not a Minari dataset id (None if it is one)."""
    match = MINARI_ID.fullmatch(dataset_id) if isinstance(dataset_id, str) else None
    if match is None or ".." in dataset_id or (need_version and match["version"] is None):
        return (
            f"{str(dataset_id)[:120]!r} is not a Minari dataset id (expected namespace/name-vN, e.g. "
            f"pcpg/mygame-v0: letters, digits, '_', '-', '/')"
        )
    return None


#: Step B's scores computed from the log itself (any other ``score`` names a table column)
BUILTIN_SCORES = ("return", "length", "-length")


class TrajectoriesConfig(StrictModel):
    """A user's own play logs (domain ``trajectories``): see docs/bring-your-own-data.md."""

    path: str | None = Field(
        None,
        description="a Parquet file, a folder of Parquet files (read in name "
        "order), or minari:DATASET_ID (a local Minari dataset); relative paths are "
        "relative to the config file",
    )
    score: str = Field(
        "return",
        description="Step B's skill per trajectory: 'return' (sum of reward), "
        "'length' (longer is better), '-length' (shorter is better) or the name of a "
        "per-trajectory numeric column of the table (higher is better)",
    )
    gymnasium_env: str | None = Field(
        None,
        description="optional Gymnasium id (e.g. FrozenLake-v1) to "
        "roll every trained agent out in; its observation must flatten "
        "to the table's state width and its action space be Discrete(n)",
    )
    gymnasium_kwargs: dict[str, str | int | float | bool | None] = Field(
        {}, description="keyword arguments of gymnasium.make (e.g. {is_slippery: false})"
    )
    gymnasium_success: Literal["terminated", "terminated_positive_reward", "reached_time_limit"] = (
        Field(
            "terminated",
            description="when a rollout episode counts as a success: 'terminated' (ended by the "
            "env itself, not by a time limit nor evaluation.max_steps: Taxi, MountainCar), "
            "'terminated_positive_reward' (terminated and its last reward > 0: FrozenLake, where "
            "falling in a hole also terminates) or 'reached_time_limit' (survived: cut by the "
            "env's time limit or evaluation.max_steps without terminating: CartPole)",
        )
    )
    n_actions: int | None = Field(
        None,
        ge=1,
        le=1_000_000,
        description="number of actions; default: the "
        "length of the valid lists, else the largest action + 1",
    )
    stream: Literal["auto", "on", "off"] = Field(
        "auto",
        description="run the log through ray.data in blocks instead of loading it into one "
        "process (docs/scale.md): 'auto' streams a Parquet log or Minari dataset of more than stream_above_steps "
        "rows; 'on' always, 'off' never. The streamed run clusters with k-means on per-trajectory "
        "summary features and trains every BC cell over the streamed rows with early stopping",
    )
    stream_above_steps: int = Field(
        2_000_000,
        ge=0,
        le=10**12,
        description="rows (steps) above which stream 'auto' streams the log; below it one "
        "process holds the whole log (about 2.5 GB of RSS per million 32-column steps)",
    )
    stream_epochs: int = Field(
        20,
        ge=1,
        le=10_000,
        description="most passes over the rows of a streamed BC cell; each cell stops earlier "
        "when its validation loss stops improving",
    )
    #: the longest logged trajectory's number of actions, noted when the units are made (so the
    #: rollouts, in other processes, need not read the logs again); private: not a setting, not in
    #: the config hash nor any cache key
    _longest_logged: int | None = PrivateAttr(None)

    @field_validator("path")
    @classmethod
    def _resolve(cls, v: str | None, info: ValidationInfo) -> str | None:
        if v is None or v.startswith("minari:"):
            return v
        return str(relative_to_config(Path(v), info))

    @field_validator("score")
    @classmethod
    def _score(cls, v: str) -> str:
        if not v.strip():
            raise ValueError("score must be return, length, -length or a column name")
        return v

    def check(self) -> None:
        if self.path is None:
            raise ValueError(
                "domain 'trajectories' needs trajectories.path (a Parquet file, a folder of "
                "Parquet files or minari:DATASET_ID)"
            )
        if self.path.startswith("minari:"):
            problem = minari_id_problem(self.path.removeprefix("minari:"))
            if problem:  # checked here, before anything reads the folder the id would name
                raise ValueError(f"trajectories.path: {problem}")
            return
        if not Path(self.path).exists():
            raise ValueError(f"trajectories.path {self.path} not found")


#: The trajectories domain's config sections, by YAML key (registered through the registry's
#: BUILTIN_SECTIONS)
SECTIONS: dict[str, type[BaseModel]] = {"trajectories": TrajectoriesConfig}
