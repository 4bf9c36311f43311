"""Base class of every config model: strict (unknown keys rejected), frozen, documented fields."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class StrictModel(BaseModel):
    """A frozen pydantic model that rejects unknown keys, wrong types and, in every float field,
    NaN and infinities (no setting of pcpg means anything at NaN or infinity) at load time."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=False, validate_default=True,
                              allow_inf_nan=False)
