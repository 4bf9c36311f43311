"""Experiment configs: pydantic models only, so loading a YAML imports no stage module and no torch.

- :mod:`.experiment`: :class:`ExperimentConfig`, :func:`load_config`, :func:`parse_config`
- :mod:`.stages`: one model per stage (clustering, ranking, BC, evaluation, PBTG, tuning, runner)
- :mod:`.domains`: the built-in domains' settings
"""

from pcpg_dist.config.domains import (
    GridWorldConfig,
    MarioLoadConfig,
    MiniDungeonsConfig,
    TrajectoriesConfig,
)
from pcpg_dist.config.experiment import ExperimentConfig, load_config, parse_config
from pcpg_dist.config.stages import (
    BCConfig,
    ClusterConfig,
    EvalConfig,
    PBTGConfig,
    RankConfig,
    RunnerConfig,
    TuneConfig,
)

__all__ = [
    "BCConfig",
    "ClusterConfig",
    "EvalConfig",
    "ExperimentConfig",
    "GridWorldConfig",
    "MarioLoadConfig",
    "MiniDungeonsConfig",
    "PBTGConfig",
    "RankConfig",
    "RunnerConfig",
    "TrajectoriesConfig",
    "TuneConfig",
    "load_config",
    "parse_config",
]
