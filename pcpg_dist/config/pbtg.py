"""Config of PBTG (section ``pbtg``): Q-learning and trajectory sampling of the built-in grid."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator

from pcpg_dist.common.memory import check_memory
from pcpg_dist.config.limits import MAX_COUNT, MAX_EPISODE_STEPS
from pcpg_dist.config.schema import StrictModel


class PBTGConfig(StrictModel):
    """Q-learning and trajectory sampling for GridWorld."""

    episodes: Annotated[
        int, Field(ge=1, le=MAX_COUNT, description="Q-learning episodes per (E, R) (paper: 20000)")
    ] = 20_000
    gamma: Annotated[float, Field(gt=0, le=1, description="discount factor of Q-learning")] = 0.99
    learning_rate: Annotated[float, Field(gt=0, le=1, description="Q-learning step size")] = 0.5
    epsilon_start: Annotated[
        float, Field(ge=0, le=1, description="exploration rate at the first episode")
    ] = 1.0
    epsilon_end: Annotated[
        float, Field(ge=0, le=1, description="exploration rate at the last episode (linear decay)")
    ] = 0.05
    trajectories_per_style: Annotated[
        int, Field(ge=1, description="trajectories generated per (E, R) (paper: 8000)")
    ] = 8000
    dataset_per_style: Annotated[
        int,
        Field(
            ge=1,
            description="trajectories per style sampled into each environment's dataset D (paper: 1000)",
        ),
    ] = 1000
    noise_min: Annotated[
        float, Field(ge=0, le=1, description="lower end of the per-trajectory noise range")
    ] = 0.0
    noise_max: Annotated[
        float, Field(ge=0, le=1, description="upper end of the per-trajectory noise range")
    ] = 0.3
    max_steps: Annotated[
        int,
        Field(ge=1, le=MAX_EPISODE_STEPS, description="episode cap; reaching it counts as failure"),
    ] = 100
    initial_q: Annotated[
        float,
        Field(
            ge=-1e6,
            le=1e6,
            description="initial Q-value of every action; optimistic (>= the best return) "
            "makes Q-learning try every route before settling",
        ),
    ] = 200.0

    @model_validator(mode="after")
    def _ranges(self) -> PBTGConfig:
        if self.noise_min > self.noise_max:
            raise ValueError(
                f"noise_min ({self.noise_min}) must be <= noise_max ({self.noise_max})"
            )
        if self.dataset_per_style > self.trajectories_per_style:
            raise ValueError(
                f"dataset_per_style ({self.dataset_per_style}) must be <= "
                f"trajectories_per_style ({self.trajectories_per_style})"
            )
        # sample_trajectories keeps each trajectory's states and actions (int64) at full length
        check_memory(
            self.trajectories_per_style * (self.max_steps + 1) * 16.0,
            f"sampling {self.trajectories_per_style} trajectories of up to {self.max_steps} steps "
            f"per (layout, style)",
            "pbtg.trajectories_per_style or pbtg.max_steps",
        )
        return self
