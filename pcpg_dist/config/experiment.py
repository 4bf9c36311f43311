"""The experiment config: one YAML file, validated at load into a frozen pydantic model.

Each stage's and each built-in domain's settings are their own models (:mod:`.stages`,
:mod:`.domains`); this module composes them. ``domain:`` takes any registered domain name
(:mod:`pcpg_dist.domains.registry`); a third-party domain's settings sit under a section of its own
name, validated by the domain's ``settings_model``. A bad file fails at load with one line naming
the key, the value and what is allowed (:class:`~pcpg_dist.errors.ConfigError`).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Annotated, Any

import yaml
from pydantic import Field, ValidationError, field_validator, model_validator

from pcpg_dist.config.domains import (
    GridWorldConfig,
    MarioLoadConfig,
    MiniDungeonsConfig,
    TrajectoriesConfig,
    safe_name,
)
from pcpg_dist.config.stages import (
    BCConfig,
    ClusterConfig,
    EvalConfig,
    PBTGConfig,
    RankConfig,
    RunnerConfig,
    TuneConfig,
)
from pcpg_dist.errors import ConfigError, PcpgError
from pcpg_dist.schema import StrictModel

MAX_SHOWN = 200  # characters of a value quoted in an error message


class ExperimentConfig(StrictModel):
    """A whole experiment: data, clustering, ranking, BC, evaluation and fan-out."""

    name: Annotated[str, Field(description="experiment name (MLflow experiment, output folder)")]
    domain: Annotated[str, Field(description="a registered domain: gridworld, minidungeons, mario, "
                                             "trajectories, or a plugin's name (`pcpg domains` lists them)")] = "gridworld"
    seed: Annotated[int, Field(ge=0, le=2**32 - 1, description="base seed of data generation")] = 0
    seeds: Annotated[list[int], Field(min_length=1, description="repetition seeds (clustering, split, BC init); "
                                                                "results report mean and std over them")] = [0, 1, 2, 3]
    gridworld: GridWorldConfig = GridWorldConfig()
    minidungeons: MiniDungeonsConfig = MiniDungeonsConfig()
    mario: MarioLoadConfig = MarioLoadConfig()
    trajectories: TrajectoriesConfig = TrajectoriesConfig()
    pbtg: PBTGConfig = PBTGConfig()
    plugin: Annotated[dict[str, Any], Field(description="settings of a third-party domain; written in "
                                                         "YAML under the domain's own name")] = {}
    clustering: ClusterConfig = ClusterConfig()
    ranking: RankConfig = RankConfig()
    bc: BCConfig = BCConfig()
    evaluation: EvalConfig = EvalConfig()
    runner: RunnerConfig = RunnerConfig()
    tuning: Annotated[TuneConfig, Field(description="`pcpg tune`: search space, objective and study "
                                                   "(ignored by `pcpg run`)")] = TuneConfig()

    @model_validator(mode="before")
    @classmethod
    def _plugin_section(cls, data: Any) -> Any:
        """A plugin domain's section (named after the domain) becomes ``plugin``."""
        if isinstance(data, dict):
            dom = data.get("domain")
            if isinstance(dom, str) and dom in data and dom not in cls.model_fields:
                data = {**data, "plugin": data[dom]}
                del data[dom]
        return data

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        return safe_name(v, "experiment name")

    @field_validator("domain")
    @classmethod
    def _domain(cls, v: str) -> str:
        from pcpg_dist.domains import registry

        try:
            registry.target(v)
        except ConfigError as e:
            raise ValueError(str(e)) from None
        return v

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, v: list[int]) -> list[int]:
        if any(s < 0 or s > 2**32 - 1 for s in v) or len(set(v)) != len(v):
            raise ValueError("seeds must be distinct integers in 0..2^32-1")
        return v

    @property
    def domain_object(self):
        """The registered :class:`~pcpg_dist.domains.base.Domain` this config names."""
        from pcpg_dist.domains import registry

        return registry.get(self.domain)

    @property
    def settings(self) -> Any:
        """The selected domain's own settings model (``cfg.gridworld`` for GridWorld, ...)."""
        return self.domain_object.settings(self)

    def hash(self) -> str:
        """Content hash of what determines a sweep's results (paths included): `tuning` (used only
        by `pcpg tune`) and `runner` (how work is spread) are left out, so editing them reuses
        the sweep's MLflow parent run."""
        return hashlib.sha256(self.model_dump_json(exclude={"tuning", "runner"}).encode()).hexdigest()[:16]

    def flat(self) -> dict[str, str]:
        """Flattened ``section.key -> value`` strings, for MLflow params."""
        out: dict[str, str] = {}

        def walk(prefix: str, value: Any) -> None:
            if isinstance(value, dict) and value:
                for k, v in value.items():
                    walk(f"{prefix}.{k}" if prefix else k, v)
            else:
                out[prefix] = json.dumps(value) if isinstance(value, list | tuple | dict) else str(value)

        walk("", self.model_dump(mode="json"))
        return out


def _shown(value: Any) -> str:
    text = "{...}" if isinstance(value, dict) else repr(value)
    return text if len(text) <= MAX_SHOWN else text[:MAX_SHOWN] + f"... ({len(text)} characters)"


def _describe(error: dict) -> str:
    key = ".".join(str(p) for p in error["loc"]) or "(top level)"
    shown = "missing" if error["type"] == "missing" else _shown(error.get("input"))
    msg = error["msg"].removeprefix("Value error, ")
    if len(msg) > 2 * MAX_SHOWN:
        msg = msg[: 2 * MAX_SHOWN] + "..."
    if error["type"] == "extra_forbidden":
        return f"unknown key '{key}' — not a setting of this section (check the spelling)"
    return f"key '{key}': value {shown} is not allowed — {msg}"


def parse_config(data: Any, source: str = "<config>", base_dir: Path | None = None) -> ExperimentConfig:
    """Validate a config mapping; raise :class:`ConfigError` with a one-line message."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a config must be a YAML mapping of keys to values")
    try:
        cfg = ExperimentConfig.model_validate(data, context={"base_dir": base_dir})
    except ValidationError as e:
        errors = e.errors(include_url=False)
        more = f" (and {len(errors) - 1} more problem(s))" if len(errors) > 1 else ""
        raise ConfigError(f"{source}: {_describe(errors[0])}{more}") from None
    try:  # the chosen domain's own settings and checks (files exist, a plugin's section, ...)
        cfg.domain_object.check_config(cfg)
    except (PcpgError, ValueError) as e:
        raise ConfigError(f"{source}: {e}") from None
    return cfg


def load_config(path: str | Path) -> ExperimentConfig:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise ConfigError(f"{path}: cannot read config ({e.strerror})") from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: not UTF-8 text (byte {e.start})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark else ""
        raise ConfigError(f"{path}{where}: not valid YAML ({getattr(e, 'problem', e)})") from None
    return parse_config(data, source=str(path), base_dir=path.parent)
