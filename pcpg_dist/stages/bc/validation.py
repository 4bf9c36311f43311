"""Checks of a trained ensemble's files and of an inference call's action masks.

Why separate from :class:`~pcpg_dist.stages.bc.trained.TrainedCells`: model files come from disk
(a cache, a published agent, an ONNX export's input), so every field is checked with a message
that names the file before any number is used; the checks are the file format's contract.
"""

from __future__ import annotations

import reprlib
from pathlib import Path

import numpy as np

from pcpg_dist.common.errors import DataError

ACTIVATIONS = ("relu", "tanh")  # BCConfig.activation's values (both have an ONNX operator)
CELL_KINDS = ("pcpg", "nc", "corrupt")  # CellSpec.kind


def check_cells(source: Path | str, cells) -> None:
    """A DataError naming ``source`` unless the cells' JSON (specs, sizes, activation) agrees
    with their weights: one spec per weight set, ``W{l}`` of shape (cells, sizes[l], sizes[l+1]),
    ``b{l}`` (cells, sizes[l+1]), mean and std (cells, sizes[0]), p in (0, 1]."""
    sizes, n = cells.sizes, len(cells.specs)
    if len(sizes) < 2 or not all(_whole(x) and x >= 1 for x in sizes):
        raise DataError(
            f"{source}: sizes {reprlib.repr(list(sizes))} must be a list of at least two "
            f"positive whole numbers (state width, hidden widths, n_actions)"
        )
    if cells.activation not in ACTIVATIONS:
        raise DataError(
            f"{source}: activation {reprlib.repr(cells.activation)} is not one of "
            f"{', '.join(ACTIVATIONS)}"
        )
    if n == 0:
        raise DataError(f"{source}: specs is empty; the file must list one spec per trained cell")
    for i, s in enumerate(cells.specs):
        _check_spec(f"{source}: specs[{i}]", s)
    if len({s.key for s in cells.specs}) != n:
        raise DataError(f"{source}: specs repeat a cell key; each cell needs its own")
    arrays = []
    for layer in range(len(sizes) - 1):
        arrays += [
            (f"W{layer}", cells.params[f"W{layer}"], (n, sizes[layer], sizes[layer + 1])),
            (f"b{layer}", cells.params[f"b{layer}"], (n, sizes[layer + 1])),
        ]
    arrays += [
        ("mean", cells.mean, (n, sizes[0])),
        ("std", cells.std, (n, sizes[0])),
        ("final_loss", cells.final_loss, (n,)),
    ]
    for name, value, want in arrays:
        shape = np.shape(value)
        if shape[:1] != want[:1]:
            raise DataError(
                f"{source}: {n} specs for {shape[0] if shape else 0} weight sets ({name} "
                f"has shape {shape}); the file must list one spec per trained cell"
            )
        if shape != want or not np.issubdtype(np.asarray(value).dtype, np.floating):
            raise DataError(
                f"{source}: {name} has shape {shape} ({np.asarray(value).dtype}), but sizes "
                f"{list(sizes)} need {want} floats"
            )
        if name != "final_loss" and not np.isfinite(value).all():
            raise DataError(
                f"{source}: {name} holds non-finite values (NaN or inf); a trained agent's "
                f"weights are finite"
            )
    if (np.asarray(cells.std) <= 0).any():
        raise DataError(
            f"{source}: std holds values <= 0; the input scale of every feature must be positive"
        )


def _check_spec(where: str, s) -> None:
    if not isinstance(s.key, str) or not s.key:
        raise DataError(f"{where}: key {reprlib.repr(s.key)} must be a non-empty string")
    if s.kind not in CELL_KINDS:
        raise DataError(
            f"{where}: kind {reprlib.repr(s.kind)} is not one of {', '.join(CELL_KINDS)}"
        )
    for field in ("k", "seed"):
        if not _whole(getattr(s, field)):
            raise DataError(
                f"{where}: {field} {reprlib.repr(getattr(s, field))} must be a whole number"
            )
    if not _number(s.p) or not 0 < s.p <= 1:
        raise DataError(f"{where}: p {reprlib.repr(s.p)} must be a number in (0, 1]")
    if not _number(s.c) or not 0 <= s.c <= 1:
        raise DataError(f"{where}: c {reprlib.repr(s.c)} must be a number in [0, 1]")


def _whole(x) -> bool:
    return isinstance(x, int | np.integer) and not isinstance(x, bool)


def _number(x) -> bool:
    finite_number = isinstance(x, int | float | np.integer | np.floating) and not isinstance(
        x, bool
    )
    return finite_number and bool(np.isfinite(x))


def check_valid(valid: np.ndarray, rows: int, n_actions: int) -> np.ndarray:
    valid = np.asarray(valid, bool)
    if valid.shape != (rows, n_actions):
        raise DataError(f"valid must have shape ({rows}, {n_actions}), got {valid.shape}")
    if rows and not valid.any(axis=1).all():
        raise DataError("a state has no valid action")
    return valid
