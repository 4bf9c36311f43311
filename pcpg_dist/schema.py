"""Base class of every config model: strict (unknown keys rejected), frozen, documented fields."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class StrictModel(BaseModel):
    """A frozen pydantic model that rejects unknown keys and wrong types at load time."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=False, validate_default=True)
