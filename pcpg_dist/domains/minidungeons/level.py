"""MiniDungeons level files: a character grid (``stages/NAME.txt``) plus rules (``props/NAME.json``).

The shipped levels are copies of the gym-md level data (MIT, (c) 2022 Ganyariya; see
``pcpg_dist/data/minidungeons/LICENSE`` and docs/minidungeons.md) and are read from the package,
never from the checkout's ``shared/`` folder, so an installed wheel works offline.

Grid characters: ``.`` floor, ``#`` wall, ``T`` treasure, ``P`` potion, ``M`` monster, ``E`` exit,
``S`` start. Row 0 is the top line; a position is ``(row, col)``. Every malformed file raises
:class:`~pcpg_dist.common.errors.LayoutError` naming the file and the line.
"""

from __future__ import annotations

import json
from collections import deque
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from pcpg_dist.common.errors import LayoutError
from pcpg_dist.config.checks import MAX_LEVEL_BYTES
from pcpg_dist.domains.minidungeons.settings import LEVELS_TEST, LEVELS_TRAIN

# Tile codes of :attr:`Level.grid` (the start is stored as floor; its position is kept apart).
FLOOR, WALL, TREASURE, POTION, MONSTER, EXIT = 0, 1, 2, 3, 4, 5
CHAR_TILE = {".": FLOOR, "#": WALL, "T": TREASURE, "P": POTION, "M": MONSTER, "E": EXIT, "S": FLOOR}


REWARD_KEYS = ("TURN", "EXIT", "KILL", "TREASURE", "POTION", "DEAD")
#: Used when a props file has no REWARDS block (the values of gym-md's ``test`` level).
MAX_PROP = 10**6  # hit points, powers and rewards: larger values overflow the game's counters
DEFAULT_REWARDS = {
    "TURN": 1.0,
    "EXIT": 20.0,
    "KILL": 4.0,
    "TREASURE": 3.0,
    "POTION": 1.0,
    "DEAD": -20.0,
}


def data_dir() -> Path:
    """The package's own copy of the level files."""
    return Path(str(resources.files("pcpg_dist") / "data" / "minidungeons"))


@dataclass(frozen=True)
class Props:
    """A level's rules, from its props JSON (gym-md's key names in the comments)."""

    max_hp: int  # PLAYER_MAX_HP: starting and (when hp_limit) maximum hit points
    hp_limit: bool  # IS_PLAYER_HP_LIMIT (default true): potions cannot heal above max_hp
    enemy_power: int  # ENEMY_POWER: damage of a fight when power is not random
    power_min: int  # ENEMY_POWER_MIN (default ENEMY_POWER)
    power_max: int  # ENEMY_POWER_MAX (default ENEMY_POWER)
    power_random: bool  # IS_ENEMY_POWER_RANDOM (default false): damage ~ U{power_min..power_max}
    potion_power: int  # POTION_POWER: hit points a potion restores
    rewards: dict[str, float]  # REWARDS: TURN (a cost per step), EXIT, KILL, TREASURE, POTION, DEAD

    @property
    def worst_damage(self) -> int:
        """The most a single fight can cost: a player with more hit points survives any fight."""
        return self.power_max if self.power_random else self.enemy_power

    @property
    def mean_damage(self) -> float:
        return (
            (self.power_min + self.power_max) / 2 if self.power_random else float(self.enemy_power)
        )


@dataclass(frozen=True, eq=False)
class Level:
    """A validated level: tile grid, start, exit and rules."""

    name: str
    grid: np.ndarray  # (H, W) int8 tile codes, read-only
    start: tuple[int, int]  # (row, col)
    exit: tuple[int, int]
    props: Props

    @property
    def shape(self) -> tuple[int, int]:
        return self.grid.shape  # type: ignore[return-value]

    def count(self, tile: int) -> int:
        return int((self.grid == tile).sum())

    def text(self) -> str:
        chars = {v: k for k, v in CHAR_TILE.items() if k != "S"}
        rows = [[chars[int(t)] for t in row] for row in self.grid]
        rows[self.start[0]][self.start[1]] = "S"
        return "\n".join("".join(r) for r in rows) + "\n"


# --------------------------------------------------------------------------- parsing
def parse_stage(
    text: str, source: str = "<stage>"
) -> tuple[np.ndarray, tuple[int, int], tuple[int, int]]:
    """Grid, start and exit of a stage text; rows must be equally long and use known characters."""
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise LayoutError(f"{source}:1: empty stage file")
    width = len(lines[0])
    grid = np.zeros((len(lines), width), np.int8)
    starts, exits = [], []
    for r, line in enumerate(lines):
        if len(line) != width:
            raise LayoutError(
                f"{source}:{r + 1}: row has {len(line)} characters, expected {width} "
                f"(every row must be as long as the first)"
            )
        for c, ch in enumerate(line):
            if ch not in CHAR_TILE:
                raise LayoutError(
                    f"{source}:{r + 1}: unknown character {ch!r} in column {c + 1} "
                    f"(allowed: {''.join(CHAR_TILE)})"
                )
            grid[r, c] = CHAR_TILE[ch]
            if ch == "S":
                starts.append((r, c))
            elif ch == "E":
                exits.append((r, c))
    for what, found, ch in (("start", starts, "S"), ("exit", exits, "E")):
        if not found:
            raise LayoutError(f"{source}:1: no {what} ('{ch}') anywhere in the {len(lines)} lines")
        if len(found) > 1:
            raise LayoutError(
                f"{source}:{found[1][0] + 1}: a second {what} ('{ch}'); exactly one is allowed"
            )
    if exits[0] not in _reachable(grid, starts[0]):
        raise LayoutError(
            f"{source}:{exits[0][0] + 1}: the exit cannot be reached from the start "
            f"(line {starts[0][0] + 1}) through the walls"
        )
    grid.setflags(write=False)
    return grid, starts[0], exits[0]


def _reachable(grid: np.ndarray, src: tuple[int, int]) -> set[tuple[int, int]]:
    h, w = grid.shape
    seen, todo = {src}, deque([src])
    while todo:
        r, c = todo.popleft()
        for nr, nc in ((r - 1, c), (r, c + 1), (r + 1, c), (r, c - 1)):
            if 0 <= nr < h and 0 <= nc < w and grid[nr, nc] != WALL and (nr, nc) not in seen:
                seen.add((nr, nc))
                todo.append((nr, nc))
    return seen


def _key_line(text: str, key: str) -> int:
    """1-based line of ``"key"`` in a JSON text (1 when it does not appear)."""
    for i, line in enumerate(text.splitlines()):
        if f'"{key}"' in line:
            return i + 1
    return 1


def parse_props(text: str, source: str = "<props>") -> Props:
    """Rules of a props JSON text; missing or ill-typed keys raise with the file and line."""
    try:
        raw = json.loads(text)
    except json.JSONDecodeError as e:
        raise LayoutError(
            f"{source}:{e.lineno}: invalid JSON ({e.msg}, column {e.colno})"
        ) from None
    except RecursionError:
        raise LayoutError(
            f"{source}:1: JSON nested too deeply; a props file is one flat object"
        ) from None
    if not isinstance(raw, dict):
        raise LayoutError(f"{source}:1: expected a JSON object of rules, got {type(raw).__name__}")

    def number(
        key: str, default: float | None = None, positive: bool = True, integer: bool = True
    ) -> float:
        if key not in raw:
            if default is None:
                raise LayoutError(f"{source}:1: missing key '{key}'")
            return default
        v = raw[key]
        ok = isinstance(v, int | float) and not isinstance(v, bool)
        if ok and integer:
            ok = float(v).is_integer()
        if not ok or (positive and v <= 0) or abs(v) > MAX_PROP:
            kind = "a positive integer" if integer and positive else "a number"
            raise LayoutError(
                f"{source}:{_key_line(text, key)}: '{key}' must be {kind} of at most "
                f"{MAX_PROP}, got {repr(v)[:40]}"
            )
        return v

    def flag(key: str, default: bool) -> bool:
        v = raw.get(key, default)
        if not isinstance(v, bool):
            raise LayoutError(
                f"{source}:{_key_line(text, key)}: '{key}' must be true or false, got {repr(v)[:40]}"
            )
        return v

    power = int(number("ENEMY_POWER"))
    random_power = flag("IS_ENEMY_POWER_RANDOM", False)
    need_range = None if random_power else power
    pmin, pmax = (
        int(number("ENEMY_POWER_MIN", need_range)),
        int(number("ENEMY_POWER_MAX", need_range)),
    )
    if pmin > pmax:
        raise LayoutError(
            f"{source}:{_key_line(text, 'ENEMY_POWER_MIN')}: ENEMY_POWER_MIN {pmin} > "
            f"ENEMY_POWER_MAX {pmax}"
        )
    rewards_raw = raw.get("REWARDS", DEFAULT_REWARDS)
    if not isinstance(rewards_raw, dict):
        raise LayoutError(f"{source}:{_key_line(text, 'REWARDS')}: 'REWARDS' must be an object")
    rewards = {}
    for k in REWARD_KEYS:
        v = rewards_raw.get(k)
        if not isinstance(v, int | float) or isinstance(v, bool) or not abs(v) <= MAX_PROP:
            raise LayoutError(
                f"{source}:{_key_line(text, 'REWARDS')}: REWARDS.{k} missing or not a number"
            )
        rewards[k] = float(v)
    return Props(
        max_hp=int(number("PLAYER_MAX_HP")),
        hp_limit=flag("IS_PLAYER_HP_LIMIT", True),
        enemy_power=power,
        power_min=pmin,
        power_max=pmax,
        power_random=random_power,
        potion_power=int(number("POTION_POWER")),
        rewards=rewards,
    )


def read_level(stage_path: str | Path, props_path: str | Path, name: str | None = None) -> Level:
    """A level from a stage file and a props file anywhere on disk (a user's own levels)."""
    stage_path, props_path = Path(stage_path), Path(props_path)
    for p in (stage_path, props_path):
        if not p.is_file():
            raise LayoutError(
                f"{p}:1: level file not found" + (" (not a regular file)" if p.exists() else "")
            )
        if p.stat().st_size > MAX_LEVEL_BYTES:
            raise LayoutError(
                f"{p}:1: {p.stat().st_size} bytes; a level file may hold at most {MAX_LEVEL_BYTES}"
            )
    texts = []
    for p in (stage_path, props_path):
        try:
            texts.append(p.read_text(encoding="utf-8"))
        except UnicodeDecodeError as e:
            raise LayoutError(f"{p}:1: not a UTF-8 text file ({e.reason})") from None
    stage_text, props_text = texts
    grid, start, exit_ = parse_stage(stage_text, str(stage_path))
    props = parse_props(props_text, str(props_path))
    return Level(name=name or stage_path.stem, grid=grid, start=start, exit=exit_, props=props)


_CACHE: dict[str, Level] = {}


def level_names() -> list[str]:
    """Names of the shipped levels (train then test, the paper's order)."""
    return [*LEVELS_TRAIN, *LEVELS_TEST]


def load_level(name: str) -> Level:
    """A shipped level by name (cached: levels are immutable)."""
    if name not in _CACHE:
        if name not in level_names():
            raise LayoutError(
                f"<minidungeons>:1: unknown level '{name}'; shipped: {', '.join(level_names())}"
            )
        d = data_dir()
        _CACHE[name] = read_level(d / "stages" / f"{name}.txt", d / "props" / f"{name}.json", name)
    return _CACHE[name]
