"""Mario's config section ``mario``: how a play log is read into a Dataset. Pydantic only, so the
registry can read it when a config is loaded without importing the log reader.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, Field, ValidationInfo, field_validator

from pcpg_dist.config.checks import check_text_file, relative_to_config
from pcpg_dist.config.schema import StrictModel

Goal = Literal["no_death", "any", "won_level"]
EventEncoding = Literal["onehot", "id"]

MAX_PLAY_LOG_BYTES = (
    64 << 20
)  # a play log is read whole, ~5x its size in Python objects (shipped: 1.1 MB)


class MarioLoadConfig(StrictModel):
    """How to read a Mario play log into a Dataset (the options of :func:`load_play_log`)."""

    path: Path | None = Field(
        None,
        description="S-TLI play log to read; None = the log shipped "
        "with the package (225 human episodes).",
    )
    strict: bool = Field(
        True,
        description="Fail with DataError on the first malformed step or "
        "episode; when false, skip it and report what was skipped.",
    )
    goal: Goal = Field(
        "no_death",
        description="Which episodes reached the goal (Performance, "
        "Eq. 3): 'no_death' = ends with the death counter at 0; 'any' = every "
        "episode; 'won_level' = the final event is 17 (inferred level-won event).",
    )
    event: EventEncoding = Field(
        "onehot",
        description="How the current event id enters the "
        "state: 'onehot' = 39 indicator features event_0..event_38; 'id' "
        "= the id as one number, as in the log (an arbitrary scale: a BC "
        "model then scores below the majority-class baseline).",
    )
    counters: bool = Field(
        True,
        description="Include the five cumulative counters (jumps .. "
        "deaths since the episode began).",
    )
    increments: bool = Field(
        False, description="Append the five per-step counter increments (d_jumps .. d_deaths)."
    )

    @field_validator("path")
    @classmethod
    def _resolve(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        return None if v is None else relative_to_config(v, info)

    def check(self) -> None:
        if self.path is not None:
            check_text_file(self.path, "mario.path play log", MAX_PLAY_LOG_BYTES, utf8=False)


#: Mario's config sections, by YAML key (registered through the registry's BUILTIN_SECTIONS)
SECTIONS: dict[str, type[BaseModel]] = {"mario": MarioLoadConfig}
