"""One line of an S-TLI play log: its steps parsed and checked, the episode's arrays built.

A line is one episode: steps ``j,k,r,c,d,e`` separated by ``|`` (five cumulative counters and
the event id), closed by a ``#0,0,0#`` terminator. What is wrong with a line is reported through a
:class:`Tally`, which raises at once in strict mode and otherwise counts and keeps the message,
so :func:`pcpg_dist.domains.mario.log.load_play_log` reads a file line by line and nothing more.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pcpg_dist.common.errors import DataError
from pcpg_dist.domains.mario.settings import EventEncoding, Goal

N_ACTIONS = 39  # CorpusIndex runs 0..38 (README of the data; all 39 occur in the shipped log)
COUNTERS = ("jumps", "kills", "run_starts", "coins", "deaths")
FIELDS_PER_STEP = len(COUNTERS) + 1  # the counters and the event
DEATHS = COUNTERS.index("deaths")

#: Final event of the 138 episodes that (as far as the data shows) finished the level: it occurs
#: only as a final step, and 91 of those episodes have no death. The other final event, 22,
#: closes 86 episodes, 65 of them after a third death. Inferred from the data, not documented.
WON_LEVEL_EVENT = 17

MAX_COUNTER = (
    2**24
)  # float32 states hold counters exactly up to here; a human episode counts hundreds


def is_terminator(text: str) -> bool:
    return len(text) >= 2 and text.startswith("#") and text.endswith("#")


def parse_step(text: str) -> tuple[list[int] | None, str]:
    """Six integers from ``'j,k,r,c,d,e'``, or None and why not."""
    parts = text.split(",")
    if len(parts) != FIELDS_PER_STEP:
        return (
            None,
            f"expected {FIELDS_PER_STEP} comma-separated integers, got {len(parts)} fields ({text[:60]!r})",
        )
    try:
        values = [int(p) for p in parts]
    except ValueError:
        return None, f"not an integer in {text[:60]!r}"
    if max(values[:-1]) > MAX_COUNTER:
        return None, f"counter above {MAX_COUNTER} in {text[:60]!r}"
    if min(values[:-1]) < 0:
        return None, f"negative counter in {text[:60]!r}"
    if not 0 <= values[-1] < N_ACTIONS:
        return None, f"event id {values[-1]} outside 0..{N_ACTIONS - 1} in {text[:60]!r}"
    return values, ""


def episode_success(steps: np.ndarray, goal: Goal) -> bool:
    if goal == "no_death":
        return bool(steps[-1, DEATHS] == 0)
    if goal == "won_level":
        return bool(steps[-1, -1] == WON_LEVEL_EVENT)
    return True


def episode_arrays(
    steps: np.ndarray, event: EventEncoding, counters: bool, increments: bool
) -> dict[str, np.ndarray]:
    """States, next-event actions, all-valid mask and zero rewards of one episode."""
    parts = [steps[:, : DEATHS + 1]] if counters else []
    parts.append(np.eye(N_ACTIONS)[steps[:, -1]] if event == "onehot" else steps[:, -1:])
    if increments:
        # Counters start from an implicit zero before the first step (18 shipped episodes open
        # on a kill, so their first step already counts 1): the first increment is steps[0].
        parts.append(np.diff(steps[:, : DEATHS + 1], axis=0, prepend=0))
    states = np.concatenate(parts, axis=1).astype(np.float32)
    return {
        "states": states,
        "actions": steps[1:, -1],
        "valid": np.ones((len(steps), N_ACTIONS), bool),
        "rewards": np.zeros(len(steps) - 1),
    }


@dataclass
class Tally:
    """What a play log's reading left out: each problem's message and the counts by kind."""

    strict: bool
    problems: list[str] = field(default_factory=list)
    skipped_steps: int = 0
    skipped_episodes: int = 0
    unterminated: int = 0
    blank: int = 0

    def problem(self, message: str) -> None:
        """Raise it (strict) or keep it."""
        if self.strict:
            raise DataError(message)
        self.problems.append(message)


def parse_episode(line: str, where: str, tally: Tally) -> np.ndarray | None:
    """One non-blank line's steps as a (steps, 6) int64 array; None where the episode is dropped
    (no readable step, or a cumulative counter that decreases)."""
    fields = [f.strip() for f in line.split("|")]
    while fields and fields[-1] == "":  # tolerate a stray '|' after the terminator
        fields.pop()
    if fields and is_terminator(fields[-1]):
        fields.pop()
    else:
        tally.unterminated += 1
        tally.problem(f"{where}: no '#0,0,0#' terminator at the end of the line (truncated?)")
    steps: list[list[int]] = []
    for step_no, field_text in enumerate(fields):
        values, why = parse_step(field_text)
        if values is None:
            tally.skipped_steps += 1
            tally.problem(f"{where} step {step_no}: {why}")
        else:
            steps.append(values)
    if not steps:
        tally.skipped_episodes += 1
        tally.problem(f"{where}: no readable step")
        return None
    arr = np.asarray(steps, dtype=np.int64)
    down = np.diff(arr[:, : DEATHS + 1], axis=0) < 0
    if down.any():
        step, col = (int(x) for x in np.argwhere(down)[0])
        tally.skipped_episodes += 1
        tally.problem(
            f"{where} step {step + 1}: cumulative counter '{COUNTERS[col]}' decreases "
            f"from {arr[step, col]} to {arr[step + 1, col]}"
        )
        return None
    return arr
