"""The corridor as a pcpg-dist domain: its settings, its data and its rollouts.

Only numpy and pydantic are imported at module level (:mod:`.game` defers pyarrow to ``play``):
`pcpg` imports this module when it loads a config naming ``domain: corridor``, which must stay
cheap.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from pcpg_corridor.game import EXPLORER, Corridor, generate, rollout_fn
from pcpg_dist.domains.base import Domain, DomainHooks

__version__ = "0.1.0"


class CorridorSettings(BaseModel):
    """The ``corridor:`` section of an experiment config."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    length: int = Field(
        12, ge=10, le=200, description=("cells in the corridor; the player starts in the middle")
    )
    trajectories_per_style: int = Field(
        100,
        ge=2,
        le=100_000,
        description=("noisy trajectories generated per play-style (rusher, collector, explorer)"),
    )
    noise_max: float = Field(
        0.2,
        ge=0.0,
        lt=1.0,
        description=("each trajectory's epsilon is drawn uniformly from [0, noise_max]"),
    )
    max_steps: int = Field(
        100, ge=1, description=("episode cap when generating; reaching it counts as failure")
    )

    @model_validator(mode="after")
    def _long_enough(self) -> CorridorSettings:
        explorer = Corridor(self.length).route_length(EXPLORER)
        if self.max_steps < explorer:
            raise ValueError(
                f"max_steps ({self.max_steps}) is shorter than the explorer's route "
                f"({explorer} steps in a corridor of {self.length})"
            )
        return self


class CorridorDomain(Domain):
    """Three scripted play-styles in a one-row corridor (see :mod:`pcpg_corridor.game`)."""

    name = "corridor"
    settings_model = CorridorSettings

    def data_key(self, cfg) -> list[Any]:
        # the package version too: a new release may generate other data from the same settings
        return [*super().data_key(cfg), __version__]

    def generate(self, cfg, show_progress: bool = True):
        s = self.settings(cfg)
        ds = generate(
            Corridor(s.length), s.trajectories_per_style, s.noise_max, s.max_steps, seed=cfg.seed
        )
        return {ds.env: ds}

    def hooks(self, cfg, unit: str) -> DomainHooks:
        corridor = Corridor(self.settings(cfg).length)
        return DomainHooks(rollout=rollout_fn(corridor, cfg.evaluation.max_steps))
