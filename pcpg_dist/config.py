"""Experiment configs: one YAML file, validated at load into frozen pydantic models.

Each stage owns its config model (``PBTGConfig`` in :mod:`pcpg_dist.pbtg`, ``ClusterConfig`` in
:mod:`pcpg_dist.clustering`, …); this module composes them. A bad file fails at load with one line
naming the key, the value and what is allowed (:class:`~pcpg_dist.errors.ConfigError`).
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import Field, ValidationError, ValidationInfo, field_validator, model_validator

from pcpg_dist.bc import BCConfig
from pcpg_dist.clustering import ClusterConfig
from pcpg_dist.domains.mario import MarioLoadConfig
from pcpg_dist.domains.minidungeons.level import LEVELS_TEST, LEVELS_TRAIN, level_names
from pcpg_dist.errors import ConfigError
from pcpg_dist.evaluation import EvalConfig
from pcpg_dist.pbtg import PBTGConfig
from pcpg_dist.ranking import RankConfig
from pcpg_dist.schema import StrictModel
from pcpg_dist.tuning import TuneConfig

NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]*$"


def _safe_name(value: str, what: str) -> str:
    """Names become folder and run names: no path separators, no '..', nothing absolute."""
    if not re.match(NAME_PATTERN, value) or ".." in value:
        raise ValueError(f"{what} {value!r} must be letters, digits, '_', '.', '-' (no '/', no '..')")
    return value


class GridWorldConfig(StrictModel):
    """Which GridWorld layouts to use."""

    layout_dir: Annotated[Path, Field(description="folder of layout files NAME.txt; relative paths are "
                                                  "relative to the config file")] = Path("gridworlds")
    environments: Annotated[list[str], Field(min_length=1, description="layout names (files "
                                             "layout_dir/NAME.txt)")] = ["E1", "E2", "E3", "E4", "E5"]

    @field_validator("layout_dir")
    @classmethod
    def _resolve(cls, v: Path, info: ValidationInfo) -> Path:
        base = (info.context or {}).get("base_dir")
        return (Path(base) / v).resolve() if base is not None and not v.is_absolute() else v

    @field_validator("environments")
    @classmethod
    def _names(cls, v: list[str]) -> list[str]:
        for name in v:
            _safe_name(name, "environment name")
        if len(set(v)) != len(v):
            raise ValueError("environment names must be unique")
        return v

    def layout_path(self, env: str) -> Path:
        return self.layout_dir / f"{env}.txt"


class MiniDungeonsConfig(StrictModel):
    """Which MiniDungeons levels train and test the agents, and how the proxies play."""

    train_levels: Annotated[list[str], Field(min_length=1, description="levels whose trajectories train "
                                             "the agents (paper: test, hard, random_1, random_2, gene_1, "
                                             "gene_2, strand_1)")] = list(LEVELS_TRAIN)
    test_levels: Annotated[list[str], Field(min_length=1, description="held-out levels for accuracy and "
                                            "rollouts (paper: holmgard_1, 2, 4, 6, 9, 10)")] = list(LEVELS_TEST)
    runs_per_level: Annotated[int, Field(ge=1, description="episodes per (level, proxy) (paper: 10)")] = 10
    noise_min: Annotated[float, Field(ge=0, le=1, description="lower end of a run's proxy noise")] = 0.0
    noise_max: Annotated[float, Field(ge=0, le=1, description="upper end of a run's proxy noise")] = 0.2
    max_steps: Annotated[int, Field(ge=1, description="turn cap of an episode (a cap is a failure)")] = 200

    @model_validator(mode="after")
    def _levels(self) -> MiniDungeonsConfig:
        known = set(level_names())
        for key in ("train_levels", "test_levels"):
            for lv in getattr(self, key):
                if lv not in known:
                    raise ValueError(f"unknown level {lv!r} in {key}; available: {', '.join(sorted(known))}")
        overlap = set(self.train_levels) & set(self.test_levels)
        if overlap:
            raise ValueError(f"levels {sorted(overlap)} are both train and test levels")
        if self.noise_min > self.noise_max:
            raise ValueError("noise_min must be <= noise_max")
        return self


class RunnerConfig(StrictModel):
    """How work is fanned out on Ray."""

    group_size: Annotated[int, Field(ge=1, description="BC cells trained together in one Ray task")] = 125
    cpus_per_task: Annotated[int, Field(ge=1, description="CPUs (and torch threads) per Ray task")] = 1


class ExperimentConfig(StrictModel):
    """A whole experiment: data, clustering, ranking, BC, evaluation and fan-out."""

    name: Annotated[str, Field(description="experiment name (MLflow experiment, output folder)")]
    domain: Annotated[Literal["gridworld", "minidungeons", "mario"], Field(description="which domain")] = "gridworld"
    seed: Annotated[int, Field(ge=0, description="base seed of data generation")] = 0
    seeds: Annotated[list[int], Field(min_length=1, description="repetition seeds (clustering, split, BC init); "
                                                                "results report mean and std over them")] = [0, 1, 2, 3]
    gridworld: GridWorldConfig = GridWorldConfig()
    minidungeons: MiniDungeonsConfig = MiniDungeonsConfig()
    mario: MarioLoadConfig = MarioLoadConfig()
    pbtg: PBTGConfig = PBTGConfig()
    clustering: ClusterConfig = ClusterConfig()
    ranking: RankConfig = RankConfig()
    bc: BCConfig = BCConfig()
    evaluation: EvalConfig = EvalConfig()
    runner: RunnerConfig = RunnerConfig()
    tuning: Annotated[TuneConfig, Field(description="`pcpg tune`: search space, objective and study "
                                                   "(ignored by `pcpg run`)")] = TuneConfig()

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        return _safe_name(v, "experiment name")

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, v: list[int]) -> list[int]:
        if any(s < 0 for s in v) or len(set(v)) != len(v):
            raise ValueError("seeds must be distinct non-negative integers")
        return v

    @model_validator(mode="after")
    def _layouts_exist(self) -> ExperimentConfig:
        if self.domain == "gridworld":
            for env in self.gridworld.environments:
                if not self.gridworld.layout_path(env).is_file():
                    raise ValueError(f"layout file {self.gridworld.layout_path(env)} for environment "
                                     f"{env!r} not found (key gridworld.environments)")
        return self

    def hash(self) -> str:
        """Content hash of what determines a sweep's results (paths included): `tuning` (used only
        by `pcpg tune`) and `runner` (how work is spread) are left out, so editing them reuses
        the sweep's MLflow parent run."""
        return hashlib.sha256(self.model_dump_json(exclude={"tuning", "runner"}).encode()).hexdigest()[:16]

    def flat(self) -> dict[str, str]:
        """Flattened ``section.key -> value`` strings, for MLflow params."""
        out: dict[str, str] = {}

        def walk(prefix: str, value: Any) -> None:
            if isinstance(value, dict):
                for k, v in value.items():
                    walk(f"{prefix}.{k}" if prefix else k, v)
            else:
                out[prefix] = json.dumps(value) if isinstance(value, list | tuple) else str(value)

        walk("", self.model_dump(mode="json"))
        return out


def _describe(error: dict) -> str:
    key = ".".join(str(p) for p in error["loc"]) or "(top level)"
    value = error.get("input")
    shown = "missing" if error["type"] == "missing" else repr(value)
    if isinstance(value, dict):
        shown = "{...}"
    msg = error["msg"].removeprefix("Value error, ")
    if error["type"] == "extra_forbidden":
        return f"unknown key '{key}' — not a setting of this section (check the spelling)"
    return f"key '{key}': value {shown} is not allowed — {msg}"


def parse_config(data: Any, source: str = "<config>", base_dir: Path | None = None) -> ExperimentConfig:
    """Validate a config mapping; raise :class:`ConfigError` with a one-line message."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a config must be a YAML mapping of keys to values")
    try:
        return ExperimentConfig.model_validate(data, context={"base_dir": base_dir})
    except ValidationError as e:
        errors = e.errors(include_url=False)
        more = f" (and {len(errors) - 1} more problem(s))" if len(errors) > 1 else ""
        raise ConfigError(f"{source}: {_describe(errors[0])}{more}") from None


def load_config(path: str | Path) -> ExperimentConfig:
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise ConfigError(f"{path}: cannot read config ({e.strerror})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark else ""
        raise ConfigError(f"{path}{where}: not valid YAML ({getattr(e, 'problem', e)})") from None
    return parse_config(data, source=str(path), base_dir=path.parent)
