"""The six MiniDungeons player proxies: hand-crafted planners, one per play-style.

Each proxy is a priority list of (target, metric) goals over :class:`~.game.Game`'s distance
fields, re-planned every turn (so it recovers from its own noisy moves). The metrics say how a
proxy treats monsters: ``plain`` walks through them (fights), ``safe`` never enters one, ``averse``
fights only when there is no other way, ``careful`` and ``pure`` are ``safe`` variants (see
:mod:`.game`). Skill varies by ``epsilon``: with that probability a turn is
a uniformly random valid move instead of the plan.

Style ids (the Dataset's ``styles``) follow the paper's order:

====  =====================  ===============================================================
id    proxy                  plan (first reachable goal wins; exit ``averse`` last for all)
====  =====================  ===============================================================
0     Safe Runner            exit, avoiding fights and giving monsters a berth (averse)
1     Reckless Runner        a monster within two steps while healthy; exit by the shortest
                             way, fighting whatever stands on it (plain)
2     Brave Treasure Hunter  healthy: nearest treasure by the shortest way, guarded or not
                             (plain); hurt: a potion, then treasure, reachable without a fight
3     Pure Treasure Hunter   nearest treasure reachable without a fight, leaving potions (pure)
4     Safety-First           nearest treasure or potion away from monsters (careful); healthy:
                             a guarded potion (averse) — the potion pays the fight back
5     Monster Killer         healthy: nearest monster (plain); hurt: a potion reachable without
                             a fight
====  =====================  ===============================================================

"Healthy" means hit points above the level's worst damage (ENEMY_POWER_MAX when random),
so no proxy *seeks* a fight that may kill it. The Reckless Runner still walks its shortest way
out through monsters when hurt, and dies of it; the others die only of forced fights (a way out
lined with monsters) or of noisy moves.
"""

from __future__ import annotations

import numpy as np

from pcpg_dist.domains.minidungeons.game import AVERSE, CAREFUL, ITEMS, PLAIN, PURE, SAFE, Game
from pcpg_dist.domains.minidungeons.level import EXIT, MONSTER, POTION, TREASURE

SAFE_RUNNER, RECKLESS_RUNNER, BRAVE_HUNTER, PURE_HUNTER, SAFETY_FIRST, MONSTER_KILLER = range(6)
PROXY_NAMES: tuple[str, ...] = (
    "Safe Runner",
    "Reckless Runner",
    "Brave Treasure Hunter",
    "Pure Treasure Hunter",
    "Safety-First",
    "Monster Killer",
)
N_PROXIES = len(PROXY_NAMES)
#: The Reckless Runner attacks monsters at most this many steps away.
SWAT_RANGE = 2.0


def _first(game: Game, goals: list[tuple[int, str]]) -> int:
    """The first move toward the first goal of the list that can be reached; -1 if none."""
    for target, metric in goals:
        a = game.direction(target, metric)
        if a >= 0:
            return a
    return -1


def plan(game: Game, proxy: int) -> int:
    """The proxy's planned move in the current state (deterministic)."""
    healthy = game.hp > game.props.worst_damage
    if proxy == SAFE_RUNNER:
        goals = [(EXIT, AVERSE)]
    elif proxy == RECKLESS_RUNNER:
        # it never walks around a monster, and swats any within two steps while it has hit points
        # to spare (it still dies when the way out is lined with monsters)
        near = game.distance(MONSTER, PLAIN) <= SWAT_RANGE
        goals = ([(MONSTER, PLAIN)] if near and healthy else []) + [(EXIT, PLAIN)]
    elif proxy == BRAVE_HUNTER:
        goals = ([(TREASURE, PLAIN)] if healthy else [(POTION, SAFE), (TREASURE, SAFE)]) + [
            (EXIT, AVERSE)
        ]
    elif proxy == PURE_HUNTER:
        goals = [(TREASURE, PURE), (EXIT, AVERSE)]
    elif proxy == SAFETY_FIRST:
        # safe items first; a guarded potion is worth a fight it surely survives (the potion pays it back)
        goals = [(ITEMS, CAREFUL)] + ([(POTION, AVERSE)] if healthy else []) + [(EXIT, AVERSE)]
    elif proxy == MONSTER_KILLER:
        goals = (
            [(MONSTER, PLAIN)] if healthy else [(POTION, SAFE)] if game.remaining(MONSTER) else []
        )
        goals = goals + [(EXIT, AVERSE)]
    else:
        raise ValueError(
            f"unknown proxy {proxy}; ids are 0..{N_PROXIES - 1} ({', '.join(PROXY_NAMES)})"
        )
    a = _first(game, goals)
    if a < 0:  # nothing reachable (cannot happen on a valid level): any valid move
        a = int(np.flatnonzero(game.valid_mask())[0])
    return a


def act(game: Game, proxy: int, epsilon: float, rng: np.random.Generator) -> int:
    """The proxy's move with noise: a uniformly random valid move with probability ``epsilon``.

    Draws exactly two numbers per call whatever the branch, so runs stay aligned across epsilons.
    """
    u, pick = rng.random(), rng.random()
    if u < epsilon:
        valid = np.flatnonzero(game.valid_mask())
        return int(valid[int(pick * len(valid))])
    return plan(game, proxy)
