"""GridWorld's config sections: ``gridworld`` (which layouts) and ``pbtg`` (PBTG's Q-learning and
trajectory sampling). Pydantic only, so the registry can read them when a config is loaded without
importing the domain's NumPy code.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import BaseModel, Field, PrivateAttr, ValidationInfo, field_validator, model_validator

from pcpg_dist.common.memory import check_memory
from pcpg_dist.config.checks import check_text_file, relative_to_config, safe_name
from pcpg_dist.config.limits import MAX_COUNT, MAX_EPISODE_STEPS
from pcpg_dist.config.schema import StrictModel

#: The paper's five GridWorld layouts E1-E5 (shipped in pcpg_dist/data/gridworld), read when
#: ``gridworld.layout_dir`` is left out, so a config anywhere runs them without naming a folder (and
#: a config's hash and its record in run.json do not depend on where pcpg is installed).
PAPER_LAYOUTS = Path(__file__).resolve().parents[2] / "data" / "gridworld"


# Layout analysis (value iteration per style, on the driver before generation starts) grows
# about as side^3: an open square layout took 0.2 s at 50x50, 1.5 s at 100x100, 13 s at 200x200
# and 118 s at 400x400, so 1000x1000 (within the byte limit) would run for half an hour unseen.
MAX_LAYOUT_SIDE = 100


def layout_size_problem(text: str) -> str | None:
    """Why a layout text is too large to analyse in a few seconds, or None (before any parsing)."""
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    height, width = len(lines), max((len(ln.rstrip("\r")) for ln in lines), default=0)
    if width <= MAX_LAYOUT_SIDE and height <= MAX_LAYOUT_SIDE:
        return None
    return (
        f"{width} columns x {height} rows; a layout may be at most {MAX_LAYOUT_SIDE}x{MAX_LAYOUT_SIDE} "
        f"cells (analysing it takes time growing as the cube of its side: 1.5 s at 100x100, minutes "
        f"beyond 300x300)"
    )


class RandomLayoutsConfig(StrictModel):
    """Random style-distinct layouts instead of layout files (units R0000, R0001, ...)."""

    count: int = Field(ge=1, le=10_000, description="number of layouts to draw")
    seed: int = Field(
        0,
        ge=0,
        description="layout i is drawn from the seed sequence (seed, i): the same "
        "(count, seed) always gives the same layouts, and a larger count only adds layouts",
    )

    @property
    def names(self) -> list[str]:
        return [f"R{i:04d}" for i in range(self.count)]


class GridWorldConfig(StrictModel):
    """Which GridWorld layouts to use: layout files, or ``random_layouts`` drawn by the generator."""

    layout_dir: Annotated[
        Path | None,
        Field(
            description="folder of layout files NAME.txt; relative paths "
            "are relative to the config file; left out: the "
            "paper's E1-E5, shipped with pcpg"
        ),
    ] = None
    environments: Annotated[
        list[str], Field(min_length=1, description="layout names (files layout_dir/NAME.txt)")
    ] = ["E1", "E2", "E3", "E4", "E5"]

    random_layouts: RandomLayoutsConfig | None = Field(
        None,
        description="{count: N, seed: S}: N random layouts (10x10, reachable goals, the four "
        "styles' optimal routes distinct), named R0000..; replaces environments and layout files",
    )

    @field_validator("layout_dir")
    @classmethod
    def _resolve(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        return None if v is None else relative_to_config(v, info)

    @model_validator(mode="after")
    def _one_source(self) -> GridWorldConfig:
        if self.random_layouts is not None and "environments" in self.model_fields_set:
            raise ValueError(
                "give either gridworld.environments (layout files) or gridworld.random_layouts, "
                "not both"
            )
        return self

    @property
    def units(self) -> list[str]:
        """The layout names: the random layouts' R0000.. or ``environments``."""
        return (
            self.random_layouts.names
            if self.random_layouts is not None
            else list(self.environments)
        )

    @field_validator("environments")
    @classmethod
    def _names(cls, v: list[str]) -> list[str]:
        for name in v:
            safe_name(name, "environment name")
        if len(set(v)) != len(v):
            raise ValueError("environment names must be unique")
        return v

    # the layout files' text, read once on the driver when the config is checked and carried with
    # the config to every task, so no worker needs the driver's disk (or sees a file edited since)
    _texts: dict[str, str] = PrivateAttr(default_factory=dict)

    def layout_path(self, env: str) -> Path:
        return (self.layout_dir or PAPER_LAYOUTS) / f"{env}.txt"

    def layout_text(self, env: str) -> str:
        if env not in self._texts:
            self._texts[env] = self.layout_path(env).read_text(encoding="utf-8")
        return self._texts[env]

    def check(self) -> None:
        if self.random_layouts is not None:
            return
        for env in self.environments:
            if not self.layout_path(env).is_file():
                raise ValueError(
                    f"layout file {self.layout_path(env)} for environment {env!r} not found "
                    f"(keys gridworld.layout_dir, gridworld.environments)"
                )
            check_text_file(
                self.layout_path(env), "layout file", folder=self.layout_dir or PAPER_LAYOUTS
            )
            if problem := layout_size_problem(self.layout_text(env)):
                raise ValueError(f"layout file {self.layout_path(env)}: {problem}")


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


#: GridWorld's config sections, by YAML key (registered through the registry's BUILTIN_SECTIONS)
SECTIONS: dict[str, type[BaseModel]] = {"gridworld": GridWorldConfig, "pbtg": PBTGConfig}
