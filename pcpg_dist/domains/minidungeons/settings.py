"""MiniDungeons' config section ``minidungeons`` and the paper's levels. Pydantic only, so the
registry can read it when a config is loaded without importing the game.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, Field, model_validator

from pcpg_dist.config.schema import StrictModel

#: The paper's MiniDungeons training and test levels (13 in all; shipped in pcpg_dist/data).
LEVELS_TRAIN: tuple[str, ...] = (
    "test",
    "hard",
    "random_1",
    "random_2",
    "gene_1",
    "gene_2",
    "strand_1",
)
LEVELS_TEST: tuple[str, ...] = (
    "holmgard_1",
    "holmgard_2",
    "holmgard_4",
    "holmgard_6",
    "holmgard_9",
    "holmgard_10",
)


class MiniDungeonsConfig(StrictModel):
    """Which MiniDungeons levels train and test the agents, and how the proxies play."""

    train_levels: Annotated[
        list[str],
        Field(
            min_length=1,
            description="levels whose trajectories train "
            "the agents (paper: test, hard, random_1, random_2, gene_1, "
            "gene_2, strand_1)",
        ),
    ] = list(LEVELS_TRAIN)
    test_levels: Annotated[
        list[str],
        Field(
            min_length=1,
            description="held-out levels for accuracy and "
            "rollouts (paper: holmgard_1, 2, 4, 6, 9, 10)",
        ),
    ] = list(LEVELS_TEST)
    runs_per_level: Annotated[
        int, Field(ge=1, le=100_000, description="episodes per (level, proxy) (paper: 10)")
    ] = 10
    noise_min: Annotated[
        float, Field(ge=0, le=1, description="lower end of a run's proxy noise")
    ] = 0.0
    noise_max: Annotated[
        float, Field(ge=0, le=1, description="upper end of a run's proxy noise")
    ] = 0.2
    max_steps: Annotated[
        int, Field(ge=1, le=100_000, description="turn cap of an episode (a cap is a failure)")
    ] = 200

    @model_validator(mode="after")
    def _levels(self) -> MiniDungeonsConfig:
        known = {*LEVELS_TRAIN, *LEVELS_TEST}
        for key in ("train_levels", "test_levels"):
            for lv in getattr(self, key):
                if lv not in known:
                    raise ValueError(
                        f"unknown level {lv!r} in {key}; available: {', '.join(sorted(known))}"
                    )
        overlap = set(self.train_levels) & set(self.test_levels)
        if overlap:
            raise ValueError(f"levels {sorted(overlap)} are both train and test levels")
        if self.noise_min > self.noise_max:
            raise ValueError("noise_min must be <= noise_max")
        return self


#: MiniDungeons' config sections, by YAML key (registered through the registry's BUILTIN_SECTIONS)
SECTIONS: dict[str, type[BaseModel]] = {"minidungeons": MiniDungeonsConfig}
