"""Base class of every config model: strict (unknown keys rejected), frozen, documented fields."""

from __future__ import annotations

import typing
from typing import Any

from pydantic import BaseModel, ConfigDict, ValidationInfo, field_validator


def _admits_bool(annotation: Any) -> bool:
    """Whether a field's type has a place for true/false (bool, Any, or a Literal of them, at any depth)."""
    if annotation is bool or annotation is Any:
        return True
    if typing.get_origin(annotation) is typing.Literal:
        return any(isinstance(a, bool) for a in typing.get_args(annotation))
    return any(_admits_bool(a) for a in typing.get_args(annotation))


def _is_numeric(annotation: Any) -> bool:
    """Whether a field's type holds an int or a float at any depth (``int``, ``list[float]``, ...)."""
    if annotation is int or annotation is float:
        return True
    return any(_is_numeric(a) for a in typing.get_args(annotation))


class StrictModel(BaseModel):
    """A frozen pydantic model that rejects unknown keys, wrong types and, in every float field,
    NaN and infinities (no setting of pcpg means anything at NaN or infinity) at load time.

    Pydantic's lax mode reads ``true`` as 1 in a number field, so ``bc.epochs: true`` would train
    one epoch: true/false is refused in every number field (ints still fill float fields)."""

    model_config = ConfigDict(
        extra="forbid", frozen=True, strict=False, validate_default=True, allow_inf_nan=False
    )

    @field_validator("*", mode="before")
    @classmethod
    def _no_booleans_for_numbers(cls, value: Any, info: ValidationInfo) -> Any:
        items = value if isinstance(value, list | tuple) else (value,)
        if any(isinstance(v, bool) for v in items) and info.field_name in cls.model_fields:
            annotation = cls.model_fields[info.field_name].annotation
            if _is_numeric(annotation) and not _admits_bool(annotation):
                raise ValueError("true/false is not a number; give a number")
        return value
