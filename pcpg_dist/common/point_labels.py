"""How a sweep's points are named: the shortest unambiguous tail of each override key and a point's
label built from it (MLflow run names, chart legends, the sweep page), kept below tracking and
reporting so both name points alike."""

from __future__ import annotations

import json
from typing import Any


def short_keys(keys: list[str]) -> dict[str, str]:
    """Each dotted key's shortest tail that no other key ends with: ``clustering.k`` -> ``k``,
    unless another key (``pbtg.k``) ends in ``k`` too (then ``clustering.k``)."""
    out = {}
    for key in keys:
        parts = key.split(".")
        for n in range(1, len(parts) + 1):
            tail = ".".join(parts[-n:])
            if not any(o != key and (o == tail or o.endswith("." + tail)) for o in keys):
                break
        out[key] = tail
    return out


def point_label(params: dict[str, str]) -> str:
    """A sweep point's name in MLflow: its axis values, short keys first (``noise_max=0.3 k=4``),
    so the runs table, the sweep's child list and chart legends show them before any cut."""
    short = short_keys(list(params))
    return " ".join(f"{short[k]}={v}" for k, v in params.items())


def axis_text(v: Any) -> str:
    """A swept value as it is written in labels and tables: JSON for lists, dicts, booleans and
    None, ``str`` for the rest (sweep tables, MLflow params, point labels and figures)."""
    return json.dumps(v) if isinstance(v, list | dict | bool) or v is None else str(v)
