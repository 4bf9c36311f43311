"""pcpg-dist: play-style-centric agents from gameplay data, at any scale.

The public face, grouped as Gymnasium groups its ``__all__``; every name is imported when first
used, so ``import pcpg_dist`` stays light (no torch, Ray or MLflow). docs/api.md lists them.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: public name -> "module:attribute", by group
_GROUPS: dict[str, dict[str, str]] = {
    "commands": {
        "run": "pcpg_dist.api.calls:run",
        "cluster": "pcpg_dist.api.calls:cluster",
        "sweep": "pcpg_dist.api.calls:sweep",
        "classify": "pcpg_dist.api.calls:classify",
        "run_experiment": "pcpg_dist.api.run:run_experiment",
        "RunResult": "pcpg_dist.orchestration.points:RunResult",
        "SweepResult": "pcpg_dist.api.sweep:SweepResult",
    },
    "configs": {
        "load_config": "pcpg_dist.config:load_config",
        "parse_config": "pcpg_dist.config:parse_config",
        "ExperimentConfig": "pcpg_dist.config:ExperimentConfig",
    },
    "data": {
        "Dataset": "pcpg_dist.dataset:Dataset",
        "load_datasets": "pcpg_dist.dataset:load_datasets",
        "write_datasets": "pcpg_dist.dataset:write_datasets",
    },
    "domains": {
        "Domain": "pcpg_dist.domains.base:Domain",
        "DomainHooks": "pcpg_dist.domains.base:DomainHooks",
        "Unit": "pcpg_dist.domains.base:Unit",
        "check_domain": "pcpg_dist.domains.check:check_domain",
    },
    "pipeline": {
        "PIPELINE": "pcpg_dist.pipeline.declared:PIPELINE",
        "Stage": "pcpg_dist.pipeline.declared:Stage",
        "run_unit": "pcpg_dist.pipeline.units:run_unit",
        "LocalExecutor": "pcpg_dist.orchestration.executors:LocalExecutor",
        "RayExecutor": "pcpg_dist.orchestration.executors:RayExecutor",
    },
    "errors": {
        "PcpgError": "pcpg_dist.common.errors:PcpgError",
        "ConfigError": "pcpg_dist.common.errors:ConfigError",
        "DataError": "pcpg_dist.common.errors:DataError",
        "DomainError": "pcpg_dist.common.errors:DomainError",
    },
}
_TARGETS = {name: target for group in _GROUPS.values() for name, target in group.items()}
__all__ = ["__version__", *_TARGETS]


def __getattr__(name: str) -> Any:
    target = _TARGETS.get(name)
    if target is None:
        raise AttributeError(f"module 'pcpg_dist' has no attribute {name!r}")
    module, _, attribute = target.partition(":")
    value = getattr(importlib.import_module(module), attribute)
    globals()[name] = value  # imported once
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
