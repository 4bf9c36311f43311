"""Which domains exist: the built-ins plus every ``pcpg_dist.domains`` entry point.

Modelled on Gymnasium's registry: a name maps to ``"module:attribute"`` and the module is imported
only when the domain is used, so listing names (an unknown ``domain:`` in a config, ``pcpg
domains``) imports nothing heavy. A third-party package registers a domain in its pyproject::

    [project.entry-points."pcpg_dist.domains"]
    my_game = "my_game.pcpg:MyGameDomain"

The attribute is a :class:`~pcpg_dist.domains.base.Domain` subclass or instance.

A domain's config sections (:func:`sections`) are read when a config is loaded: a built-in's from a
light, pydantic-only ``settings`` module (:data:`BUILTIN_SECTIONS`), so a config names no domain
code it does not run; a plugin's from its Domain class, through its entry point.
"""

from __future__ import annotations

import difflib
from importlib import import_module
from importlib.metadata import entry_points
from typing import TYPE_CHECKING

from pcpg_dist.common.errors import ConfigError

if TYPE_CHECKING:
    from pydantic import BaseModel

ENTRY_POINT_GROUP = "pcpg_dist.domains"

#: name -> "module:attribute" of the built-in domains
BUILTIN: dict[str, str] = {
    "gridworld": "pcpg_dist.domains.gridworld.domain:GridWorldDomain",
    "minidungeons": "pcpg_dist.domains.minidungeons.domain:MiniDungeonsDomain",
    "mario": "pcpg_dist.domains.mario.domain:MarioDomain",
    "trajectories": "pcpg_dist.domains.trajectories.domain:TrajectoriesDomain",
}

#: name -> "module:attribute" of each built-in domain's config sections ({YAML key: model}), in
#: modules that import pydantic only
BUILTIN_SECTIONS: dict[str, str] = {
    "gridworld": "pcpg_dist.domains.gridworld.settings:SECTIONS",
    "minidungeons": "pcpg_dist.domains.minidungeons.settings:SECTIONS",
    "mario": "pcpg_dist.domains.mario.settings:SECTIONS",
    "trajectories": "pcpg_dist.domains.trajectories.settings:SECTIONS",
}

#: the domain a config without ``domain:`` runs
DEFAULT_DOMAIN = "gridworld"

_loaded: dict[str, object] = {}


def _entry_points() -> dict[str, str]:
    return {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}


def names() -> list[str]:
    """Every registered domain name, built-ins first."""
    plugins = sorted(n for n in _entry_points() if n not in BUILTIN)
    return [*BUILTIN, *plugins]


def target(name: str) -> str:
    """The ``module:attribute`` a name points at; a one-line ConfigError listing the names if unknown."""
    found = BUILTIN.get(name) or _entry_points().get(name)
    if found is None:
        close = difflib.get_close_matches(name, names(), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ConfigError(f"unknown domain {name!r}{hint}; registered: {', '.join(names())}")
    return found


def get(name: str):
    """The domain object registered under ``name`` (imported on first use, then cached)."""
    if name not in _loaded:
        where = target(name)
        module, _, attr = where.partition(":")
        try:
            obj = getattr(import_module(module), attr)
        except (ImportError, AttributeError) as e:
            raise ConfigError(
                f"domain {name!r}: cannot load {where} ({type(e).__name__}: {e})"
            ) from None
        from pcpg_dist.domains.base import Domain

        if not (isinstance(obj, Domain) or (isinstance(obj, type) and issubclass(obj, Domain))):
            raise ConfigError(
                f"domain {name!r}: {where} is {obj!r}, not a pcpg_dist.domains.base.Domain "
                f"(subclass of it, or an instance); docs/writing-a-domain.md shows one"
            )
        obj = obj() if isinstance(obj, type) else obj
        if getattr(obj, "name", None) != name:
            raise ConfigError(
                f"domain {name!r}: {where} has name {getattr(obj, 'name', None)!r}; the "
                f"entry point and the domain's `name` must agree"
            )
        _loaded[name] = obj
    return _loaded[name]


def is_registered(name: object) -> bool:
    """Whether ``name`` is a registered domain name (imports nothing)."""
    return isinstance(name, str) and (name in BUILTIN or name in _entry_points())


def sections(name: str) -> dict[str, type[BaseModel]]:
    """The config sections of domain ``name`` ({YAML key: pydantic model}): a built-in's from its
    settings module (its domain module is not imported), a plugin's from its Domain class."""
    where = BUILTIN_SECTIONS.get(name)
    if where is None:
        return get(name).section_models()
    module, _, attr = where.partition(":")
    return dict(getattr(import_module(module), attr))
