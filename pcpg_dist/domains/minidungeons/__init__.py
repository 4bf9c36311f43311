"""MiniDungeons: PCPG's second synthetic domain (six player proxies on 13 dungeon levels).

See docs/minidungeons.md for the rules, the proxies and the 15 state features.
"""

from pcpg_dist.domains.minidungeons.data import (
    DOMAIN,
    default_dataset,
    generate_trajectories,
    outcome_stats,
    part_seed,
    play,
    rollout,
)
from pcpg_dist.domains.minidungeons.env import MiniDungeonsEnv
from pcpg_dist.domains.minidungeons.game import (
    DEFAULT_MAX_STEPS,
    FEATURES,
    N_ACTIONS,
    STATE_DIM,
    Game,
)
from pcpg_dist.domains.minidungeons.level import (
    LEVELS_TEST,
    LEVELS_TRAIN,
    Level,
    Props,
    level_names,
    load_level,
    parse_props,
    parse_stage,
    read_level,
)
from pcpg_dist.domains.minidungeons.proxies import N_PROXIES, PROXY_NAMES, act, plan

__all__ = [
    "DEFAULT_MAX_STEPS",
    "DOMAIN",
    "FEATURES",
    "LEVELS_TEST",
    "LEVELS_TRAIN",
    "N_ACTIONS",
    "N_PROXIES",
    "PROXY_NAMES",
    "STATE_DIM",
    "Game",
    "Level",
    "MiniDungeonsEnv",
    "Props",
    "act",
    "default_dataset",
    "generate_trajectories",
    "level_names",
    "load_level",
    "outcome_stats",
    "parse_props",
    "parse_stage",
    "part_seed",
    "plan",
    "play",
    "read_level",
    "rollout",
]
