"""The experiment config: one YAML file, validated at load into a frozen pydantic model.

Each stage's and each built-in domain's settings are their own models (:mod:`.stages`,
:mod:`.domains`); this module composes them. ``domain:`` takes any registered domain name
(:mod:`pcpg_dist.domains.registry`); a third-party domain's settings sit under a section of its own
name, validated by the domain's ``settings_model``. A bad file fails at load with one line naming
the key, the value and what is allowed (:class:`~pcpg_dist.common.errors.ConfigError`).
"""

from __future__ import annotations

import hashlib
import json
import reprlib
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, Field, ValidationError, field_validator, model_validator

from pcpg_dist.common.errors import ConfigError, PcpgError
from pcpg_dist.common.messages import MAX_SHOWN, one_line, settable_keys, unknown_key_message
from pcpg_dist.config.domains import (
    GridWorldConfig,
    MarioLoadConfig,
    MiniDungeonsConfig,
    TrajectoriesConfig,
    safe_name,
)
from pcpg_dist.config.schema import StrictModel
from pcpg_dist.config.stages import (
    LIKELIHOOD_METHODS,
    BCConfig,
    ClusterConfig,
    EvalConfig,
    PBTGConfig,
    RankConfig,
    RunnerConfig,
    TuneConfig,
)
from pcpg_dist.config.yaml_io import read_yaml

#: the sections that hold one domain's settings (a run logs only its own domain's)
DOMAIN_SECTIONS = ("gridworld", "minidungeons", "mario", "trajectories", "pbtg", "plugin")


class ExperimentConfig(StrictModel):
    """A whole experiment: data, clustering, ranking, BC, evaluation and fan-out."""

    name: Annotated[str, Field(description="experiment name (MLflow experiment, output folder)")]
    domain: Annotated[
        str,
        Field(
            description="a registered domain: gridworld, minidungeons, mario, "
            "trajectories, or a plugin's name (`pcpg domains` lists them)"
        ),
    ] = "gridworld"
    seed: Annotated[int, Field(ge=0, le=2**32 - 1, description="base seed of data generation")] = 0
    seeds: Annotated[
        list[int],
        Field(
            min_length=1,
            max_length=1000,
            description="repetition seeds (clustering, split, BC init); "
            "results report mean and std over them",
        ),
    ] = [0, 1, 2, 3]
    gridworld: GridWorldConfig = GridWorldConfig()
    minidungeons: MiniDungeonsConfig = MiniDungeonsConfig()
    mario: MarioLoadConfig = MarioLoadConfig()
    trajectories: TrajectoriesConfig = TrajectoriesConfig()
    pbtg: PBTGConfig = PBTGConfig()
    plugin: Annotated[
        dict[str, Any],
        Field(
            description="settings of a third-party domain; written in "
            "YAML under the domain's own name"
        ),
    ] = {}
    clustering: ClusterConfig = ClusterConfig()
    ranking: RankConfig = RankConfig()
    bc: BCConfig = BCConfig()
    evaluation: EvalConfig = EvalConfig()
    runner: RunnerConfig = RunnerConfig()
    tuning: Annotated[
        TuneConfig,
        Field(description="`pcpg tune`: search space, objective and study (ignored by `pcpg run`)"),
    ] = TuneConfig()

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

    @model_validator(mode="after")
    def _corruption_needs_two_clusters(self) -> ExperimentConfig:
        """Corrupting labels moves trajectories to *other* clusters: with one there is none."""
        if self.clustering.k < 2 and any(c > 0 for c in self.evaluation.corruption_levels):
            raise ValueError(
                "clustering.k = 1 leaves no other cluster to corrupt labels into: set "
                "evaluation.corruption_levels to [0.0], or clustering.k to 2 or more"
            )
        return self

    @model_validator(mode="after")
    def _style_margin_needs_a_likelihood(self) -> ExperimentConfig:
        """A style margin is a likelihood ratio: only the clusterers with a likelihood give one."""
        if self.ranking.style_margin > 0 and self.clustering.method not in LIKELIHOOD_METHODS:
            raise ValueError(
                f"ranking.style_margin needs a clusterer with a likelihood "
                f"(clustering.method {', '.join(LIKELIHOOD_METHODS)}); "
                f"{self.clustering.method} gives none: set ranking.style_margin to 0"
            )
        return self

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
        return hashlib.sha256(
            self.model_dump_json(exclude={"tuning", "runner"}).encode()
        ).hexdigest()[:16]

    def flat(self) -> dict[str, str]:
        """Flattened ``section.key -> value`` strings, for MLflow params: the sections that act on
        a run (`tuning`, which `pcpg run` ignores, and the other domains' sections are left out:
        a GridWorld run's page listed ~40 params of Mario, MiniDungeons, logs and tuning)."""
        out: dict[str, str] = {}
        unused = {"tuning", *DOMAIN_SECTIONS} - set(self.domain_object.config_sections())

        def walk(prefix: str, value: Any) -> None:
            if isinstance(value, dict) and value:
                for k, v in value.items():
                    walk(f"{prefix}.{k}" if prefix else k, v)
            else:
                out[prefix] = (
                    json.dumps(value) if isinstance(value, list | tuple | dict) else str(value)
                )

        walk("", self.model_dump(mode="json", exclude=unused))
        return out


_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxtuple, _REPR.maxdict, _REPR.maxset = 3, 8, 8, 6, 6
_REPR.maxstring = _REPR.maxother = MAX_SHOWN
_REPR.maxlong = 60


def _shown(value: Any) -> str:
    """A value quoted in an error message: never more than a few hundred characters, and built
    without the full ``repr`` of a huge value (an alias bomb's repr would be gigabytes)."""
    text = "{...}" if isinstance(value, dict) else _REPR.repr(value)
    return text if len(text) <= MAX_SHOWN else text[:MAX_SHOWN] + "..."


def valid_keys(domain: str | None = None) -> list[str]:
    """Every dotted key a config can set (a plugin domain's own keys are checked by its model)."""
    keys = settable_keys(ExperimentConfig)
    if domain:
        from pcpg_dist.domains import registry

        try:
            model = registry.get(domain).settings_model
        except Exception:  # noqa: BLE001 - an unknown domain is reported by the config itself
            model = None
        if (
            isinstance(model, type)
            and issubclass(model, BaseModel)
            and domain not in ExperimentConfig.model_fields
        ):
            keys += settable_keys(model, domain + ".")
    return keys


def _describe(error: dict, domain: str | None = None) -> str:
    key = one_line(".".join(str(p) for p in error["loc"]), MAX_SHOWN) or "(top level)"
    shown = "missing" if error["type"] == "missing" else _shown(error.get("input"))
    msg = error["msg"].removeprefix("Value error, ").replace("\n", " ")
    if len(msg) > 2 * MAX_SHOWN:
        msg = msg[: 2 * MAX_SHOWN] + "..."
    if error["type"] == "extra_forbidden":
        return unknown_key_message(key, valid_keys(domain))
    if isinstance(error.get("input"), dict) and error["type"] == "value_error":
        # a check across keys: the message names them
        return f"section '{key}': {msg}" if error["loc"] else msg
    return f"key '{key}': value {shown} is not allowed — {msg}"


def parse_config(
    data: Any, source: str = "<config>", base_dir: Path | None = None
) -> ExperimentConfig:
    """Validate a config mapping; raise :class:`ConfigError` with a one-line message."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a config must be a YAML mapping of keys to values")
    try:
        cfg = ExperimentConfig.model_validate(data, context={"base_dir": base_dir})
    except ValidationError as e:
        errors = e.errors(include_url=False)
        more = f" (and {len(errors) - 1} more problem(s))" if len(errors) > 1 else ""
        domain = data.get("domain") if isinstance(data.get("domain"), str) else None
        raise ConfigError(one_line(f"{source}: {_describe(errors[0], domain)}{more}")) from None
    from pcpg_dist.domains.contract import calling

    try:  # the chosen domain's own settings and checks (files exist, a plugin's section, ...)
        with calling(
            cfg.domain_object, "check_config"
        ):  # a plugin's other exceptions: one line too
            cfg.domain_object.check_config(cfg)
    except (PcpgError, ValueError) as e:
        raise ConfigError(one_line(f"{source}: {e}")) from None
    return cfg


def load_config(path: str | Path) -> ExperimentConfig:
    path = Path(path)
    return parse_config(read_yaml(path), source=str(path), base_dir=path.parent)
