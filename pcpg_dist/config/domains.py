"""Config models of the built-in domains: pydantic only (no stage, no torch, no data read).

A domain's section is checked further by its ``check()`` only when ``domain:`` selects it, so the
defaults of the other sections (say a GridWorld layout folder in a Mario config) never fail a load.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, PrivateAttr, ValidationInfo, field_validator, model_validator

from pcpg_dist.config.schema import StrictModel

NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]*$"
MAX_NAME = 100  # names become folder and file names (255 bytes at most on common file systems)

#: The paper's MiniDungeons training and test levels (13 in all; shipped in pcpg_dist/data).
LEVELS_TRAIN: tuple[str, ...] = (
    "test",
    "hard",
    "random_1",
    "random_2",
    "gene_1",
    "gene_2",
    "strand_1",
)
LEVELS_TEST: tuple[str, ...] = (
    "holmgard_1",
    "holmgard_2",
    "holmgard_4",
    "holmgard_6",
    "holmgard_9",
    "holmgard_10",
)

#: The paper's five GridWorld layouts E1-E5 (shipped in pcpg_dist/data/gridworld), read when
#: ``gridworld.layout_dir`` is left out, so a config anywhere runs them without naming a folder (and
#: a config's hash and its record in run.json do not depend on where pcpg is installed).
PAPER_LAYOUTS = Path(__file__).resolve().parents[1] / "data" / "gridworld"

Goal = Literal["no_death", "any", "won_level"]
EventEncoding = Literal["onehot", "id"]


#: a Minari dataset id, ``[namespace/]name[-vN]`` (Minari's own grammar; a namespace may hold '/'):
#: never a path
MINARI_ID = re.compile(
    r"^(?:(?P<namespace>[-_\w][-_\w/]*[-_\w]+)/)?(?P<name>[-_\w]+?)(?:-v(?P<version>\d+))?$"
)


def minari_id_problem(dataset_id: object, need_version: bool = False) -> str | None:
    """Why ``dataset_id`` is not a Minari dataset id (None if it is one)."""
    match = MINARI_ID.fullmatch(dataset_id) if isinstance(dataset_id, str) else None
    if match is None or ".." in dataset_id or (need_version and match["version"] is None):
        return (
            f"{str(dataset_id)[:120]!r} is not a Minari dataset id (expected namespace/name-vN, e.g. "
            f"pcpg/mygame-v0: letters, digits, '_', '-', '/')"
        )
    return None


def safe_name(value: str, what: str) -> str:
    """Names become folder and run names: no path separators, no '..', nothing absolute."""
    if len(value) > MAX_NAME:
        raise ValueError(
            f"{what} {value[:40]!r}... has {len(value)} characters; at most {MAX_NAME} are allowed"
        )
    if not re.match(NAME_PATTERN, value) or ".." in value:
        raise ValueError(
            f"{what} {value!r} must be letters, digits, '_', '.', '-' (no '/', no '..')"
        )
    return value


MAX_LEVEL_BYTES = 1 << 20  # a level or layout file is a screenful of characters
MAX_PLAY_LOG_BYTES = (
    64 << 20
)  # a play log is read whole, ~5x its size in Python objects (shipped: 1.1 MB)


# Layout analysis (value iteration per style, on the driver before generation starts) grows
# about as side^3: an open square layout took 0.2 s at 50x50, 1.5 s at 100x100, 13 s at 200x200
# and 118 s at 400x400, so 1000x1000 (within the byte limit) would run for half an hour unseen.
MAX_LAYOUT_SIDE = 100


def layout_size_problem(text: str) -> str | None:
    """Why a layout text is too large to analyse in a few seconds, or None (before any parsing)."""
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    height, width = len(lines), max((len(ln.rstrip("\r")) for ln in lines), default=0)
    if width <= MAX_LAYOUT_SIDE and height <= MAX_LAYOUT_SIDE:
        return None
    return (
        f"{width} columns x {height} rows; a layout may be at most {MAX_LAYOUT_SIDE}x{MAX_LAYOUT_SIDE} "
        f"cells (analysing it takes time growing as the cube of its side: 1.5 s at 100x100, minutes "
        f"beyond 300x300)"
    )


def check_text_file(
    path: Path, what: str, max_bytes: int = MAX_LEVEL_BYTES, utf8: bool = True
) -> None:
    """A file the config points at must be a regular file of at most ``max_bytes`` bytes of UTF-8
    text (a FIFO or /dev/zero would block or never end; a binary file is the wrong file)."""
    if not path.is_file():
        raise ValueError(
            f"{what} {path} " + ("is not a regular file" if path.exists() else "not found")
        )
    size = path.stat().st_size
    if size > max_bytes:
        raise ValueError(
            f"{what} {path} has {size} bytes; at most {max_bytes} are allowed (wrong file?)"
        )
    if not utf8:
        return
    raw = path.read_bytes()
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise ValueError(
            f"{what} {path}, line {line}: not UTF-8 text (byte {e.start}); save it as UTF-8"
        ) from None


def relative_to_config(v: Path, info: ValidationInfo) -> Path:
    """Relative paths in a config file are relative to the file's folder; ``~`` is the home folder."""
    v = v.expanduser()
    base = (info.context or {}).get("base_dir")
    return (Path(base) / v).resolve() if base is not None and not v.is_absolute() else v


class RandomLayoutsConfig(StrictModel):
    """Random style-distinct layouts instead of layout files (units R0000, R0001, ...)."""

    count: int = Field(ge=1, le=10_000, description="number of layouts to draw")
    seed: int = Field(
        0,
        ge=0,
        description="layout i is drawn from the seed sequence (seed, i): the same "
        "(count, seed) always gives the same layouts, and a larger count only adds layouts",
    )

    @property
    def names(self) -> list[str]:
        return [f"R{i:04d}" for i in range(self.count)]


class GridWorldConfig(StrictModel):
    """Which GridWorld layouts to use: layout files, or ``random_layouts`` drawn by the generator."""

    layout_dir: Annotated[
        Path | None,
        Field(
            description="folder of layout files NAME.txt; relative paths "
            "are relative to the config file; left out: the "
            "paper's E1-E5, shipped with pcpg"
        ),
    ] = None
    environments: Annotated[
        list[str], Field(min_length=1, description="layout names (files layout_dir/NAME.txt)")
    ] = ["E1", "E2", "E3", "E4", "E5"]

    random_layouts: RandomLayoutsConfig | None = Field(
        None,
        description="{count: N, seed: S}: N random layouts (10x10, reachable goals, the four "
        "styles' optimal routes distinct), named R0000..; replaces environments and layout files",
    )

    @field_validator("layout_dir")
    @classmethod
    def _resolve(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        return None if v is None else relative_to_config(v, info)

    @model_validator(mode="after")
    def _one_source(self) -> GridWorldConfig:
        if self.random_layouts is not None and "environments" in self.model_fields_set:
            raise ValueError(
                "give either gridworld.environments (layout files) or gridworld.random_layouts, "
                "not both"
            )
        return self

    @property
    def units(self) -> list[str]:
        """The layout names: the random layouts' R0000.. or ``environments``."""
        return (
            self.random_layouts.names
            if self.random_layouts is not None
            else list(self.environments)
        )

    @field_validator("environments")
    @classmethod
    def _names(cls, v: list[str]) -> list[str]:
        for name in v:
            safe_name(name, "environment name")
        if len(set(v)) != len(v):
            raise ValueError("environment names must be unique")
        return v

    # the layout files' text, read once on the driver when the config is checked and carried with
    # the config to every task, so no worker needs the driver's disk (or sees a file edited since)
    _texts: dict[str, str] = PrivateAttr(default_factory=dict)

    def layout_path(self, env: str) -> Path:
        return (self.layout_dir or PAPER_LAYOUTS) / f"{env}.txt"

    def layout_text(self, env: str) -> str:
        if env not in self._texts:
            self._texts[env] = self.layout_path(env).read_text(encoding="utf-8")
        return self._texts[env]

    def check(self) -> None:
        if self.random_layouts is not None:
            return
        for env in self.environments:
            if not self.layout_path(env).is_file():
                raise ValueError(
                    f"layout file {self.layout_path(env)} for environment {env!r} not found "
                    f"(keys gridworld.layout_dir, gridworld.environments)"
                )
            check_text_file(self.layout_path(env), "layout file")
            if problem := layout_size_problem(self.layout_text(env)):
                raise ValueError(f"layout file {self.layout_path(env)}: {problem}")


class MiniDungeonsConfig(StrictModel):
    """Which MiniDungeons levels train and test the agents, and how the proxies play."""

    train_levels: Annotated[
        list[str],
        Field(
            min_length=1,
            description="levels whose trajectories train "
            "the agents (paper: test, hard, random_1, random_2, gene_1, "
            "gene_2, strand_1)",
        ),
    ] = list(LEVELS_TRAIN)
    test_levels: Annotated[
        list[str],
        Field(
            min_length=1,
            description="held-out levels for accuracy and "
            "rollouts (paper: holmgard_1, 2, 4, 6, 9, 10)",
        ),
    ] = list(LEVELS_TEST)
    runs_per_level: Annotated[
        int, Field(ge=1, le=100_000, description="episodes per (level, proxy) (paper: 10)")
    ] = 10
    noise_min: Annotated[
        float, Field(ge=0, le=1, description="lower end of a run's proxy noise")
    ] = 0.0
    noise_max: Annotated[
        float, Field(ge=0, le=1, description="upper end of a run's proxy noise")
    ] = 0.2
    max_steps: Annotated[
        int, Field(ge=1, le=100_000, description="turn cap of an episode (a cap is a failure)")
    ] = 200

    @model_validator(mode="after")
    def _levels(self) -> MiniDungeonsConfig:
        known = {*LEVELS_TRAIN, *LEVELS_TEST}
        for key in ("train_levels", "test_levels"):
            for lv in getattr(self, key):
                if lv not in known:
                    raise ValueError(
                        f"unknown level {lv!r} in {key}; available: {', '.join(sorted(known))}"
                    )
        overlap = set(self.train_levels) & set(self.test_levels)
        if overlap:
            raise ValueError(f"levels {sorted(overlap)} are both train and test levels")
        if self.noise_min > self.noise_max:
            raise ValueError("noise_min must be <= noise_max")
        return self


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


class TrajectoriesConfig(StrictModel):
    """A user's own play logs (domain ``trajectories``): see docs/bring-your-own-data.md."""

    path: str | None = Field(
        None,
        description="a Parquet file, a folder of Parquet files (read in name "
        "order), or minari:DATASET_ID (a local Minari dataset); relative paths are "
        "relative to the config file",
    )
    score: str = Field(
        "return",
        description="Step B's skill per trajectory: 'return' (sum of reward), "
        "'length' (longer is better), '-length' (shorter is better) or the name of a "
        "per-trajectory numeric column of the table (higher is better)",
    )
    gymnasium_env: str | None = Field(
        None,
        description="optional Gymnasium id (e.g. FrozenLake-v1) to "
        "roll every trained agent out in; its observation must flatten "
        "to the table's state width and its action space be Discrete(n)",
    )
    gymnasium_kwargs: dict[str, str | int | float | bool | None] = Field(
        {}, description="keyword arguments of gymnasium.make (e.g. {is_slippery: false})"
    )
    gymnasium_success: Literal["terminated", "terminated_positive_reward"] = Field(
        "terminated",
        description="when a rollout episode counts as a success: 'terminated' (ended by "
        "the env, not by a time limit) or 'terminated_positive_reward' (and its last reward > 0: "
        "FrozenLake, where falling in a hole also terminates)",
    )
    n_actions: int | None = Field(
        None,
        ge=1,
        le=1_000_000,
        description="number of actions; default: the "
        "length of the valid lists, else the largest action + 1",
    )

    @field_validator("path")
    @classmethod
    def _resolve(cls, v: str | None, info: ValidationInfo) -> str | None:
        if v is None or v.startswith("minari:"):
            return v
        return str(relative_to_config(Path(v), info))

    @field_validator("score")
    @classmethod
    def _score(cls, v: str) -> str:
        if not v.strip():
            raise ValueError("score must be return, length, -length or a column name")
        return v

    def check(self) -> None:
        if self.path is None:
            raise ValueError(
                "domain 'trajectories' needs trajectories.path (a Parquet file, a folder of "
                "Parquet files or minari:DATASET_ID)"
            )
        if self.path.startswith("minari:"):
            problem = minari_id_problem(self.path.removeprefix("minari:"))
            if problem:  # checked here, before anything reads the folder the id would name
                raise ValueError(f"trajectories.path: {problem}")
            return
        if not Path(self.path).exists():
            raise ValueError(f"trajectories.path {self.path} not found")
