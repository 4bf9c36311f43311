"""MiniDungeons rules, distance fields and the 15-feature event state.

One :class:`Game` is one episode on one :class:`~.level.Level`. The Gymnasium env, the six player
proxies and the BC rollouts all drive this class, so the rules exist once.

Rules (docs/minidungeons.md has the full table):

- Actions 0 up, 1 right, 2 down, 3 left. A move off the grid or into a wall is invalid (masked);
  if one is taken anyway the player stays put and the turn still passes.
- Stepping onto a monster fights it: the monster dies, the player moves onto its cell and loses
  ``U{ENEMY_POWER_MIN..ENEMY_POWER_MAX}`` hit points (``ENEMY_POWER`` when not random).
  Hit points <= 0: dead (terminal, failure).
- Treasure and potions are collected by stepping on them; a potion heals ``POTION_POWER``,
  capped at ``PLAYER_MAX_HP`` when ``IS_PLAYER_HP_LIMIT`` (the default).
- Stepping onto the exit ends the level (terminal, success). Reaching ``max_steps`` turns
  without either ends it as a failure (truncated).
- Reward per turn: ``-TURN`` plus ``KILL``/``TREASURE``/``POTION``/``EXIT``/``DEAD`` for the events
  of that turn (the props' REWARDS). The pipeline ranks by Eq. 3, not by this reward.

Distance fields: the planners (proxies) and the state features both ask "which move leads
toward the nearest X", under a metric — ``plain`` (monsters are ordinary cells), ``safe``
(monsters impassable), ``averse`` (a monster costs 10000 extra, a cell next to one 2, so a path
fights only when there is no other way), ``careful`` (safe, +8 next to a monster, and items within
two steps of a monster are not targets) and ``pure`` (safe, +3 per potion). The exit is never passed through on the way to anything else.
Fields are multi-source Dijkstra from the targets, cached until a tile they depend on changes.
"""

from __future__ import annotations

import heapq
import math

import numpy as np

from pcpg_dist.domains.minidungeons.level import EXIT, FLOOR, MONSTER, POTION, TREASURE, WALL, Level

UP, RIGHT, DOWN, LEFT = 0, 1, 2, 3
N_ACTIONS = 4
#: (drow, dcol) per action.
MOVES = ((-1, 0), (0, 1), (1, 0), (0, -1))
PLAIN, SAFE, AVERSE, CAREFUL, PURE = "plain", "safe", "averse", "careful", "pure"
#: Extra cost of entering a monster's cell under AVERSE: more than any fight-free path can cost
#: (at most 1 + 8 per cell), so ``distance // AVERSE_PENALTY`` counts the fights on the way.
AVERSE_PENALTY = 10000.0
#: Extra cost of a cell next to a live monster under AVERSE (2) and CAREFUL (4): the cautious
#: proxies give monsters a berth when it is cheap.
MARGIN_PENALTY = {AVERSE: 2.0, CAREFUL: 8.0}
#: Extra cost of a potion under PURE: the Pure Treasure Hunter leaves potions where they lie.
POTION_PENALTY = 3.0
#: Counts and steps are divided by these fixed scales (not by level totals), so a feature means the
#: same on every level and :func:`outcome_stats` recovers exact counts from any Dataset.
COUNT_SCALE = 10.0
STEP_SCALE = 100.0
DEFAULT_MAX_STEPS = 200
ITEMS = -1  # pseudo-target: treasure or potion

FEATURES: tuple[str, ...] = (
    "hp",  # hit points / PLAYER_MAX_HP (0 once dead)
    "steps",  # turns taken / 100
    "treasure",  # treasures collected so far / 10
    "potions",  # potions drunk so far / 10
    "kills",  # monsters killed so far / 10
    "exit_dy",
    "exit_dx",  # first move toward the exit, avoiding fights where possible (averse)
    "exit_plain_dy",
    "exit_plain_dx",  # first move of the shortest way to the exit (plain)
    "treasure_dy",
    "treasure_dx",  # first move toward the nearest treasure (averse) / (1 + fights)
    "potion_dy",
    "potion_dx",  # first move toward the nearest potion (averse) / (1 + fights)
    "monster_dy",
    "monster_dx",  # first move toward the nearest monster (plain) / its distance
)
STATE_DIM = len(FEATURES)
#: (target tile, metric) of each direction pair in FEATURES, in order.
DIRECTION_FEATURES = (
    (EXIT, AVERSE),
    (EXIT, PLAIN),
    (TREASURE, AVERSE),
    (POTION, AVERSE),
    (MONSTER, PLAIN),
)


class Game:
    """One episode: mutable grid, player position, hit points and event counters.

    Randomness (fight damage) comes only from the ``rng`` passed to :meth:`step`.
    """

    def __init__(self, level: Level, max_steps: int = DEFAULT_MAX_STEPS) -> None:
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps}")
        self.level, self.props, self.max_steps = level, level.props, int(max_steps)
        h, w = level.shape
        self.height, self.width = h, w
        self.grid = level.grid.copy()
        self.pos = level.start
        self.hp = self.props.max_hp
        self.t = 0
        self.treasure = self.potions = self.kills = self.damage = 0
        self.dead = self.success = self.truncated = False
        self._fields: dict[tuple[int, str], tuple[np.ndarray, np.ndarray]] = {}

    # ------------------------------------------------------------------ state
    @property
    def over(self) -> bool:
        return self.dead or self.success or self.truncated

    @property
    def terminated(self) -> bool:
        return self.dead or self.success

    def neighbour(self, pos: tuple[int, int], action: int) -> tuple[int, int] | None:
        """The cell ``action`` leads to from ``pos``, or None when it is off the grid or a wall."""
        r, c = pos[0] + MOVES[action][0], pos[1] + MOVES[action][1]
        if 0 <= r < self.height and 0 <= c < self.width and self.grid[r, c] != WALL:
            return r, c
        return None

    def valid_mask(self) -> np.ndarray:
        return np.array([self.neighbour(self.pos, a) is not None for a in range(N_ACTIONS)])

    def remaining(self, tile: int) -> int:
        return int((self.grid == tile).sum())

    # ------------------------------------------------------------------ rules
    def step(self, action: int, rng: np.random.Generator) -> tuple[float, dict[str, int]]:
        """Play one turn; returns (reward, events of this turn). Raises if the episode is over."""
        if self.over:
            raise RuntimeError("step() on a finished episode; reset first")
        rw = self.props.rewards
        reward = -rw["TURN"]
        events = {"kill": 0, "damage": 0, "treasure": 0, "potion": 0, "heal": 0}
        nxt = self.neighbour(self.pos, int(action))
        if nxt is not None:
            self.pos = nxt
            tile = int(self.grid[nxt])
            if tile == MONSTER:
                p = self.props
                dmg = (
                    int(rng.integers(p.power_min, p.power_max + 1))
                    if p.power_random
                    else p.enemy_power
                )
                self.hp -= dmg
                self.damage += dmg
                self.kills += 1
                events.update(kill=1, damage=dmg)
                reward += rw["KILL"]
                self._clear(nxt, MONSTER)
                if self.hp <= 0:
                    self.dead = True
                    reward += rw["DEAD"]
            elif tile == TREASURE:
                self.treasure += 1
                events["treasure"] = 1
                reward += rw["TREASURE"]
                self._clear(nxt, TREASURE)
            elif tile == POTION:
                heal = self.props.potion_power
                if self.props.hp_limit:
                    heal = max(0, min(heal, self.props.max_hp - self.hp))
                self.hp += heal
                self.potions += 1
                events.update(potion=1, heal=heal)
                reward += rw["POTION"]
                self._clear(nxt, POTION)
            elif tile == EXIT:
                self.success = True
                reward += rw["EXIT"]
        self.t += 1
        if not self.terminated and self.t >= self.max_steps:
            self.truncated = True
        return reward, events

    def _clear(self, pos: tuple[int, int], tile: int) -> None:
        self.grid[pos] = FLOOR
        # Killing a monster changes every non-plain metric; a pickup changes only its own targets.
        self._fields = {
            k: v
            for k, v in self._fields.items()
            if k[0] != tile
            and not (tile == MONSTER and k[1] != PLAIN)
            and not (tile == POTION and k[1] == PURE)
            and not (k[0] == ITEMS and tile in (TREASURE, POTION))
        }

    # ------------------------------------------------------------------ distance fields
    def field(self, target: int, metric: str) -> np.ndarray:
        """(H, W) cost of the cheapest way from each cell to the nearest ``target`` tile."""
        return self._field_and_cost(target, metric)[0]

    def _field_and_cost(self, target: int, metric: str) -> tuple[np.ndarray, np.ndarray]:
        key = (target, metric)
        if key not in self._fields:
            self._fields[key] = self._dijkstra(target, metric)
        return self._fields[key]

    def _dijkstra(self, target: int, metric: str) -> tuple[np.ndarray, np.ndarray]:
        """Multi-source Dijkstra from the targets over the cost of *entering* each cell."""
        grid = self.grid
        goal = np.isin(grid, (TREASURE, POTION)) if target == ITEMS else grid == target
        cost = np.ones(grid.shape)
        monster = grid == MONSTER
        near = np.zeros_like(monster)
        near[1:] |= monster[:-1]
        near[:-1] |= monster[1:]
        near[:, 1:] |= monster[:, :-1]
        near[:, :-1] |= monster[:, 1:]
        if metric in MARGIN_PENALTY:
            cost[near] += MARGIN_PENALTY[metric]
        if metric == CAREFUL:  # an item within two steps of a monster is not worth the risk
            near2 = near.copy()
            near2[1:] |= near[:-1]
            near2[:-1] |= near[1:]
            near2[:, 1:] |= near[:, :-1]
            near2[:, :-1] |= near[:, 1:]
            goal &= ~near2
        if metric == AVERSE:
            cost[monster] += AVERSE_PENALTY
        elif metric != PLAIN:
            cost[monster] = math.inf
        if metric == PURE:
            cost[grid == POTION] += POTION_PENALTY
        if target != EXIT:
            cost[grid == EXIT] = math.inf  # stepping on the exit ends the game
        cost[goal & ~np.isfinite(cost)] = 1.0  # a target is always enterable
        cost[grid == WALL] = math.inf
        dist = np.full(grid.shape, math.inf)
        heap = [(0.0, int(r), int(c)) for r, c in zip(*np.nonzero(goal), strict=True)]
        for _, r, c in heap:
            dist[r, c] = 0.0
        heapq.heapify(heap)
        h, w = grid.shape
        while heap:
            d, r, c = heapq.heappop(heap)
            if d > dist[r, c]:
                continue
            nd = d + cost[r, c]  # a neighbour reaches (r, c) by entering it
            if not math.isfinite(nd):
                continue
            for dr, dc in MOVES:
                nr, nc = r + dr, c + dc
                if (
                    0 <= nr < h
                    and 0 <= nc < w
                    and nd < dist[nr, nc]
                    and math.isfinite(cost[nr, nc])
                ):
                    dist[nr, nc] = nd
                    heapq.heappush(heap, (nd, nr, nc))
        return dist, cost

    def distance(self, target: int, metric: str) -> float:
        return float(self.field(target, metric)[self.pos])

    def fights_to(self, target: int) -> int:
        """Fights on the cheapest AVERSE way to the nearest ``target`` (-1 when none is left)."""
        d = self.distance(target, AVERSE)
        return int(d // AVERSE_PENALTY) if math.isfinite(d) else -1

    def direction(self, target: int, metric: str) -> int:
        """Action of the first move toward the nearest ``target`` under ``metric``; -1 if none.

        Ties go to the lowest action index, so the proxies and the features agree exactly.
        """
        f, cost = self._field_and_cost(target, metric)
        if f[self.pos] == 0.0 or not math.isfinite(f[self.pos]):
            return -1
        best, best_a = math.inf, -1
        for a in range(N_ACTIONS):
            n = self.neighbour(self.pos, a)
            if n is not None and f[n] + cost[n] < best - 1e-9:
                best, best_a = f[n] + cost[n], a
        return best_a if math.isfinite(best) else -1

    # ------------------------------------------------------------------ features
    def features(self) -> np.ndarray:
        """The 15-feature event state (see FEATURES and docs/minidungeons.md for why these)."""
        out = np.zeros(STATE_DIM, np.float32)
        out[0] = max(self.hp, 0) / self.props.max_hp
        out[1] = self.t / STEP_SCALE
        out[2] = self.treasure / COUNT_SCALE
        out[3] = self.potions / COUNT_SCALE
        out[4] = self.kills / COUNT_SCALE
        for i, (target, metric) in enumerate(DIRECTION_FEATURES):
            a = self.direction(target, metric)
            if a >= 0:
                # the monster's pair shrinks with distance (1 = next to you); treasure's and
                # potion's with the fights on the way (1 = unguarded, 1/2 = one fight, ...)
                if target == MONSTER:
                    scale = 1.0 / self.distance(target, metric)
                elif target in (TREASURE, POTION):
                    scale = 1.0 / (1 + self.fights_to(target))
                else:
                    scale = 1.0
                out[5 + 2 * i], out[6 + 2 * i] = MOVES[a][0] * scale, MOVES[a][1] * scale
        return out

    def observation_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) of :meth:`features` on this level, for the env's observation space."""
        lv, p = self.level, self.props
        low = np.zeros(STATE_DIM, np.float32)
        low[5:] = -1.0
        high = np.ones(STATE_DIM, np.float32)
        if not p.hp_limit:
            high[0] = (p.max_hp + lv.count(POTION) * p.potion_power) / p.max_hp
        high[1] = self.max_steps / STEP_SCALE
        high[2] = lv.count(TREASURE) / COUNT_SCALE
        high[3] = lv.count(POTION) / COUNT_SCALE
        high[4] = lv.count(MONSTER) / COUNT_SCALE
        return low, high
