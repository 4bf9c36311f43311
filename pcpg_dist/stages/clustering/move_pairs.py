"""A game's own move features (``clustering.move_features``): the user's function, and the legal
moves of a log with what it says of each (the input of :mod:`.choice_mix`).

Where a log's move ids do not say what a move does (chess: 4,672 ids, each a from-square and a
direction), the user names a function of their own, ``"package.module:function"``, that says it:
``function(state, legal_ids) -> (len(legal_ids), F)`` numbers for the legal moves of one state
(the state as the log's row, the ids as ints, ascending), or ``(those numbers, playable)`` with
one boolean per id where the log offers ids that are not moves there (it has no action masks).
pcpg calls it once per decision step, in the clustering task, and fits :mod:`.choice_mix` to the
result. ``bag_auto`` uses it whenever
the setting is given (docs/clustering.md, "What a move does").
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

import numpy as np

from pcpg_dist.common.errors import DataError
from pcpg_dist.stages.clustering.choice_mix import ChoicePairs

KEY = "clustering.move_features"

#: ``(state, legal_ids) -> features`` or ``-> (features, playable)``
MoveFeatures = Callable[[np.ndarray, np.ndarray], np.ndarray | tuple[np.ndarray, np.ndarray]]

#: the features each (function, state, legal ids) got, so the confidence's refits on subsamples,
#: the ceiling and the model's assignments of the same log call the user's function once a step
_SEEN: dict[tuple[str, bytes, bytes], np.ndarray] = {}
MAX_SEEN = 500_000  # steps remembered; past it the memory starts again
MAX_NAME = 60  # characters of a feature's name


def load_move_features(spec: str) -> MoveFeatures:
    """The function ``spec`` ("module:function") names, or one line saying why it cannot be had."""
    module, _, name = spec.partition(":")
    try:
        found = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise DataError(
            f"{KEY}: cannot import {spec!r} ({type(exc).__name__}: {exc}); give "
            "'package.module:function' importable where pcpg runs"
        ) from None
    if not callable(found):
        raise DataError(f"{KEY}: {spec!r} is a {type(found).__name__}, not a function")
    return found


def feature_names(features: MoveFeatures, width: int, spec: str) -> list[str]:
    """What the function calls its ``width`` features: its ``names`` attribute where it has one
    (a list or tuple of ``width`` strings), else ``feature 0``, ``feature 1``, ...; one line
    where ``names`` is something else."""
    names = getattr(features, "names", None)
    if names is None:
        return [f"feature {i}" for i in range(width)]
    if not (
        isinstance(names, list | tuple)
        and len(names) == width
        and all(isinstance(n, str) and 0 < len(n) <= MAX_NAME for n in names)
    ):
        raise DataError(
            f"{KEY}: {spec}.names must be a list of {width} names (one per feature it returns, "
            f"each 1-{MAX_NAME} characters), got {type(names).__name__} "
            f"{str(names)[:80]!r}"
        )
    return list(names)


def pairs_of(dataset, features: MoveFeatures, spec: str) -> ChoicePairs:
    """Every decision step's legal moves (``valid``; the taken move counts as legal) and their
    features from ``features``, checked: one line naming the step for a wrong shape, a width that
    changes, a non-number or a NaN. Where the function also says which offered moves are
    playable (it returns ``(features, playable)``: a log without action masks offers every id),
    only those are the step's moves; the taken one must be among them."""
    offsets = np.asarray(dataset.offsets, np.int64)
    actions = np.asarray(dataset.actions, np.int64)
    phis, starts, chosen, steps_of, width = [], [0], [], [0], None
    for i in range(len(offsets) - 1):
        for row in range(offsets[i], offsets[i + 1]):
            if actions[row] < 0:
                continue
            legal = np.nonzero(dataset.valid[row])[0]
            if not dataset.valid[row, actions[row]]:
                legal = np.sort(np.append(legal, actions[row]))
            where = f"{KEY}: {spec} at trajectory {i} (row {row})"
            key = (spec, dataset.states[row].tobytes(), legal.tobytes())
            got = _SEEN.get(key)
            if got is None:
                got = _described(features, dataset.states[row], legal, where)
                if len(_SEEN) >= MAX_SEEN:
                    _SEEN.clear()
                _SEEN[key] = got
            phi, playable = got
            width = phi.shape[1] if width is None and phi.ndim == 2 else width
            if phi.shape != (len(legal), width):
                raise DataError(
                    f"{where} returned shape {phi.shape}; it must return ({len(legal)} legal "
                    f"moves, {width} features) numbers, as many features at every step"
                )
            if not np.isfinite(phi).all():
                raise DataError(f"{where} returned NaN or infinite values; all must be finite")
            if playable is not None:
                if not playable[np.searchsorted(legal, actions[row])]:
                    raise DataError(
                        f"{where} says the log's move {actions[row]} is not playable; the "
                        "move a trajectory took must be"
                    )
                phi, legal = phi[playable], legal[playable]
            phis.append(phi)
            chosen.append(starts[-1] + int(np.searchsorted(legal, actions[row])))
            starts.append(starts[-1] + len(legal))
        steps_of.append(len(chosen))
    if not chosen:
        raise DataError(f"{KEY}: the log has no decision steps to describe")
    return ChoicePairs(np.concatenate(phis), np.array(starts), np.array(chosen), np.array(steps_of))


def _described(
    features: MoveFeatures, state: np.ndarray, legal: np.ndarray, where: str
) -> tuple[np.ndarray, np.ndarray | None]:
    """(the features as float64, which offered moves are playable or None), or one line."""
    try:
        got, playable = features(state, legal), None
        if isinstance(got, tuple):
            if len(got) != 2:
                raise DataError(
                    f"{where} returned a tuple of {len(got)}; return the features, or "
                    "(features, playable)"
                )
            got, playable = got[0], np.asarray(got[1])
            if playable.dtype != np.bool_ or playable.shape != (len(legal),):
                raise DataError(
                    f"{where} returned playable of dtype {playable.dtype} and shape "
                    f"{playable.shape}; it must be {len(legal)} booleans, one per offered move"
                )
        return np.asarray(got, dtype=np.float64), playable
    except (TypeError, ValueError) as exc:
        raise DataError(f"{where} gave no numbers: {exc}") from None
