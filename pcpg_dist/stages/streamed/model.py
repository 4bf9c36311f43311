"""A streamed run's clustering as a file: what `pcpg classify` needs to label another log the
same way, block by block (``RUN/summary/model_seed<S>/streamed_model.json``).

It holds the log's layout (state columns, actions), the features' standardisation and the k
centres: a few kilobytes whatever the log's size. Plain JSON, checked field by field on reading
(shapes, finite numbers, positive scales), so a damaged or hand-edited file is one line naming
the file and the field, never a traceback or a model that gives other labels.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from pcpg_dist.common.errors import DataError
from pcpg_dist.common.files import atomic_write_bytes, read_json
from pcpg_dist.common.inputs import input_file

FILE = "streamed_model.json"
KIND = "streamed k-means"
MAX_BYTES = 64 * 2**20  # k centres of a few thousand features is far less


def feature_width(d: int, n_actions: int) -> int:
    """Features of one trajectory (:func:`~pcpg_dist.stages.streamed.features.trajectory_features`):
    log length, the action frequencies, the mean and the spread of every state column."""
    return 1 + n_actions + 2 * d


class StreamedModel(BaseModel):
    """The k-means of one seed of a streamed run, and the log layout it was fitted on."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    format: Literal[1] = 1
    kind: Literal["streamed k-means"] = KIND
    seed: int
    states: list[str] = Field(min_length=1)
    n_actions: int = Field(ge=1, le=100_000)
    mean: list[float]
    scale: list[float]
    centres: list[list[float]] = Field(min_length=1)

    @model_validator(mode="after")
    def _shapes(self) -> StreamedModel:
        f = feature_width(len(self.states), self.n_actions)
        for name, values in (("mean", self.mean), ("scale", self.scale)):
            if len(values) != f:
                raise ValueError(f"{name}: {len(values)} values; the features need {f}")
        if any(not (math.isfinite(s) and s > 0) for s in self.scale):
            raise ValueError("scale: every value must be a positive finite number")
        for i, c in enumerate(self.centres):
            if len(c) != f:
                raise ValueError(f"centres[{i}]: {len(c)} values; the features need {f}")
        values = [*self.mean, *(v for c in self.centres for v in c)]
        if not all(math.isfinite(v) for v in values):
            raise ValueError("mean and centres must be finite numbers")
        if len(set(self.states)) != len(self.states):
            raise ValueError("states: a column named twice")
        return self

    @property
    def k(self) -> int:
        return len(self.centres)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(mean, scale, centres) as float64 arrays."""
        return np.asarray(self.mean), np.asarray(self.scale), np.asarray(self.centres)

    def save(self, folder: Path) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(folder / FILE, self.model_dump_json(indent=1).encode())
        return folder / FILE


def is_streamed_model(folder: Path) -> bool:
    """Whether ``folder`` holds a streamed run's clustering (not `pcpg cluster`'s model)."""
    return (Path(folder) / FILE).is_file()


def load_streamed_model(folder: Path) -> StreamedModel:
    """The model in ``folder``, checked; a bad file is one line naming it and the field."""
    path = input_file(
        Path(folder) / FILE, "streamed model file", folder=Path(folder), max_bytes=MAX_BYTES
    )
    raw = read_json(path)
    try:
        return StreamedModel.model_validate(raw)
    except ValidationError as e:
        err = e.errors()[0]
        where = ".".join(str(p) for p in err["loc"]) or "the file"
        raise DataError(f"{path}: {where}: {err['msg']}") from None
