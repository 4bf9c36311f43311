"""The experiment config: one YAML file, validated at load into a frozen pydantic model.

:class:`ExperimentConfig` holds the core keys (name, domain, seeds and each stage's model, from
:mod:`.stages`); ``domain:`` takes any registered domain name (:mod:`pcpg_dist.domains.registry`),
and the config is validated as that domain's class (:func:`config_class`), which adds the sections
the domain declares (``Domain.sections``), defaults filled in. So this layer names no domain, every
domain registers its settings the same way, and a config's hash depends on its own domain's
sections only. Sections of the other built-in domains (an old run.json recorded them all) are
validated, then dropped. A bad file fails at load with one line naming the key, the value and what
is allowed (:class:`~pcpg_dist.common.errors.ConfigError`).
"""

from __future__ import annotations

import hashlib
import json
import reprlib
from pathlib import Path
from typing import Annotated, Any

from pydantic import (
    BaseModel,
    Field,
    ValidationError,
    create_model,
    field_validator,
    model_validator,
)

from pcpg_dist.common.errors import ConfigError, PcpgError
from pcpg_dist.common.messages import MAX_SHOWN, one_line, settable_keys, unknown_key_message
from pcpg_dist.config.checks import safe_name
from pcpg_dist.config.schema import StrictModel
from pcpg_dist.config.stages import (
    LIKELIHOOD_METHODS,
    BCConfig,
    ClusterConfig,
    EvalConfig,
    RankConfig,
    RunnerConfig,
    TuneConfig,
)
from pcpg_dist.config.yaml_io import read_yaml
from pcpg_dist.domains import registry
from pcpg_dist.domains.registry import DEFAULT_DOMAIN

#: a key of configs written before domains declared their sections (an empty mapping, or a plugin
#: domain's settings): read as the domain's own section
LEGACY_PLUGIN_KEY = "plugin"


class ExperimentConfig(StrictModel):
    """A whole experiment: data, clustering, ranking, BC, evaluation and fan-out.

    Validating one (:meth:`model_validate`, :func:`parse_config`) gives an instance of its domain's
    class (:func:`config_class`), whose extra fields are that domain's sections (``cfg.<section>``).
    """

    name: Annotated[str, Field(description="experiment name (MLflow experiment, output folder)")]
    domain: Annotated[
        str,
        Field(
            description="a registered domain: a built-in or a plugin's name "
            "(`pcpg domains` lists them)"
        ),
    ] = DEFAULT_DOMAIN
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
    clustering: ClusterConfig = ClusterConfig()
    ranking: RankConfig = RankConfig()
    bc: BCConfig = BCConfig()
    evaluation: EvalConfig = EvalConfig()
    runner: RunnerConfig = RunnerConfig()
    tuning: Annotated[
        TuneConfig,
        Field(description="`pcpg tune`: search space, objective and study (ignored by `pcpg run`)"),
    ] = TuneConfig()

    @classmethod
    def model_validate(cls, obj: Any, **kwargs: Any) -> ExperimentConfig:  # type: ignore[override]
        """Validate ``obj`` as the class of the domain it names (core keys plus that domain's
        sections); an unknown domain fails here, on the core keys, with the registered names."""
        if (
            cls is ExperimentConfig
            and isinstance(obj, dict)
            and registry.is_registered(obj.get("domain", DEFAULT_DOMAIN))
        ):
            return _validate_for_domain(obj, **kwargs)
        return super().model_validate(obj, **kwargs)

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled (Ray tasks, worker processes) by domain name and state: the class is rebuilt
        from the registry on the other side, the sections' private state (layout texts) kept."""
        return (_restore, (self.domain, self.__getstate__()))

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
        return registry.get(self.domain)

    @property
    def settings(self) -> Any:
        """The selected domain's own settings model (``cfg.gridworld`` for GridWorld, ...)."""
        return self.domain_object.settings(self)

    def hash(self) -> str:
        """Content hash of what determines a sweep's results (paths included): the core keys and
        this domain's own sections (another domain's defaults do not change it); `tuning` (used
        only by `pcpg tune`) and `runner` (how work is spread) are left out, so editing them reuses
        the sweep's MLflow parent run."""
        return hashlib.sha256(
            self.model_dump_json(exclude={"tuning", "runner"}).encode()
        ).hexdigest()[:16]

    def flat(self) -> dict[str, str]:
        """Flattened ``section.key -> value`` strings, for MLflow params: the sections that act on
        a run (`tuning`, which `pcpg run` ignores, is left out; a config holds no other domain's
        sections)."""
        out: dict[str, str] = {}
        unused = {"tuning"}

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


def valid_keys(domain: str | None = None, other_domains: bool = True) -> list[str]:
    """Every dotted key a config for ``domain`` (unknown: the default) can set: the core keys, the
    domain's sections' and, with ``other_domains``, the other built-in domains' sections' (a
    config may hold them; they are checked, then dropped)."""
    if not registry.is_registered(domain):
        domain = DEFAULT_DOMAIN
    try:
        own = registry.sections(domain)
    except Exception:  # noqa: BLE001 - a plugin that fails to load is reported by the config itself
        own = {}
    others = _other_sections(domain, None) if other_domains else {}
    keys = settable_keys(ExperimentConfig)
    for key, model in {**own, **{k: m for k, m in others.items() if k not in own}}.items():
        keys += settable_keys(model, key + ".")
    return keys


def _other_sections(domain: str, wanted: frozenset[str] | None) -> dict[str, type[BaseModel]]:
    """The other built-in domains' sections named in ``wanted`` (None: all of them)."""
    found: dict[str, type[BaseModel]] = {}
    for other in registry.BUILTIN_SECTIONS:
        if other != domain:
            for key, model in registry.sections(other).items():
                if wanted is None or key in wanted:
                    found.setdefault(key, model)
    return found


_CLASSES: dict[tuple[Any, ...], type[ExperimentConfig]] = {}


def config_class(domain: str, others: frozenset[str] = frozenset()) -> type[ExperimentConfig]:
    """:class:`ExperimentConfig` with ``domain``'s sections as fields (defaults filled in, so
    ``cfg.<section>`` always holds the domain's settings) and, when ``others`` names sections of
    other built-in domains, those as optional fields (to check a config that holds them).

    Built once per set of section models: a plugin re-registered with other models gets its own."""
    own = {
        k: m for k, m in registry.sections(domain).items() if k not in ExperimentConfig.model_fields
    }
    extra = (
        {k: m for k, m in _other_sections(domain, others).items() if k not in own} if others else {}
    )
    key = (domain, tuple(own.items()), tuple(extra.items()))
    if key not in _CLASSES:
        fields: dict[str, Any] = {
            name: (
                model,
                Field(
                    default_factory=dict,
                    validate_default=True,
                    description=(model.__doc__ or "").strip().split("\n")[0] or None,
                ),
            )
            for name, model in own.items()
        }
        fields.update({name: (model | None, None) for name, model in extra.items()})
        _CLASSES[key] = create_model(
            f"ExperimentConfig[{domain}]", __base__=ExperimentConfig, __module__=__name__, **fields
        )
    return _CLASSES[key]


def _validate_for_domain(data: dict, **kwargs: Any) -> ExperimentConfig:
    """``data`` validated as its domain's class: other built-in domains' sections are checked by
    their models, then dropped (the result holds the core keys and the domain's sections)."""
    domain = data.get("domain", DEFAULT_DOMAIN)
    legacy = data.get(LEGACY_PLUGIN_KEY)
    if LEGACY_PLUGIN_KEY in data and (isinstance(legacy, dict) or legacy is None):
        data = {k: v for k, v in data.items() if k != LEGACY_PLUGIN_KEY}
        if legacy and domain not in data:  # a plugin domain's settings, recorded before sections
            data[domain] = legacy
    plain = config_class(domain)
    others = frozenset(k for k in data if k not in plain.model_fields)
    full = config_class(domain, others) if others else plain
    cfg = full.model_validate(data, **kwargs)
    if full is plain:
        return cfg
    return plain.model_construct(
        _fields_set=cfg.model_fields_set & set(plain.model_fields),
        **{name: getattr(cfg, name) for name in plain.model_fields},
    )


def _restore(domain: str, state: dict[str, Any]) -> ExperimentConfig:
    """A pickled config back as its domain's class (see :meth:`ExperimentConfig.__reduce__`)."""
    cls = config_class(domain)
    cfg = cls.__new__(cls)
    cfg.__setstate__(state)
    return cfg


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
