"""Config of the fan-out on Ray (section ``runner``)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, field_validator

from pcpg_dist.config.schema import StrictModel


class RunnerConfig(StrictModel):
    """How work is fanned out on Ray."""

    group_size: Annotated[
        int, Field(ge=1, le=1_000_000, description="BC cells trained together in one Ray task")
    ] = 125
    cpus_per_task: Annotated[
        int,
        Field(
            ge=1,
            le=4096,
            description="CPUs (and torch threads) per Ray task; where Step A has fewer units "
            "than CPUs, each unit's clustering gets a share of every CPU instead (at most 4, "
            "at most what the smallest node has)",
        ),
    ] = 1
    gpus_per_task: Annotated[
        float,
        Field(
            gt=0,
            le=64,
            description=(
                "GPUs each Ray task of a stage on a GPU asks for (clustering.device or bc.device cuda, or "
                "auto on a cluster with GPUs): a fraction shares one GPU among tasks (0.25: four at once), "
                "above 1 a whole number"
            ),
        ),
    ] = 0.25

    @field_validator("gpus_per_task")
    @classmethod
    def _whole_above_one(cls, v: float) -> float:
        if v > 1 and v != int(v):
            raise ValueError(
                f"must be at most 1 or a whole number (Ray shares a GPU only in fractions "
                f"of one), got {v:g}"
            )
        return v
