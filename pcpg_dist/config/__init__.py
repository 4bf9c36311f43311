"""Experiment configs: pydantic models only, so loading a YAML imports no stage module and no torch.

- :mod:`.experiment`: :class:`ExperimentConfig`, :func:`load_config`, :func:`parse_config`
- :mod:`.stages`: one model per stage (clustering, ranking, BC, evaluation, tuning, runner)
- :mod:`.checks`: the checks every domain's settings share (names, files, relative paths)

Each domain's own settings live with the domain (``pcpg_dist/domains/<name>/settings.py`` for the
built-ins) and reach a config through the domain registry.
"""

from pcpg_dist.config.experiment import ExperimentConfig, load_config, parse_config
from pcpg_dist.config.stages import (
    BCConfig,
    ClusterConfig,
    EvalConfig,
    RankConfig,
    RunnerConfig,
    TuneConfig,
)

__all__ = [
    "BCConfig",
    "ClusterConfig",
    "EvalConfig",
    "ExperimentConfig",
    "RankConfig",
    "RunnerConfig",
    "TuneConfig",
    "load_config",
    "parse_config",
]
