"""MiniDungeons as a Gymnasium environment (for users and RL libraries; the pipeline uses Game)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from pcpg_dist.domains.minidungeons.game import DEFAULT_MAX_STEPS, FEATURES, N_ACTIONS, Game
from pcpg_dist.domains.minidungeons.level import Level, load_level


class MiniDungeonsEnv(gym.Env):
    """A MiniDungeons level: reach the exit, fighting, looting and drinking on the way.

    ## Action Space
    ``Discrete(4)``: 0 up, 1 right, 2 down, 3 left. :meth:`action_masks` gives the valid ones
    (moves off the grid or into a wall are invalid; taken anyway they waste the turn).

    ## Observation Space
    ``Box(15,)`` float32: the event state of :data:`~.game.FEATURES` — hit points, turns,
    treasure/potion/kill counts and the first move toward exit, treasure, potion and monster.

    ## Reward
    ``-TURN`` per turn plus the level's KILL, TREASURE, POTION, EXIT and DEAD rewards.

    ## Episode End
    Terminated on the exit (``info["success"]``) or on death (hit points <= 0); truncated after
    ``max_steps`` turns.

    ## Arguments
    ``level``: a shipped level name or a :class:`~.level.Level`; ``max_steps``: the turn cap.
    """

    metadata = {"render_modes": ["ansi"], "render_fps": 4}

    def __init__(
        self,
        level: str | Level = "test",
        max_steps: int = DEFAULT_MAX_STEPS,
        render_mode: str | None = None,
    ) -> None:
        self.level = load_level(level) if isinstance(level, str) else level
        self.max_steps = int(max_steps)
        self.render_mode = render_mode
        self.game = Game(self.level, self.max_steps)
        low, high = self.game.observation_bounds()
        self.observation_space = spaces.Box(low=low, high=high, dtype=np.float32)
        self.action_space = spaces.Discrete(N_ACTIONS)
        self.feature_names = FEATURES

    def _info(self, events: dict[str, int] | None = None) -> dict[str, Any]:
        g = self.game
        return {
            "action_mask": g.valid_mask(),
            "hp": g.hp,
            "pos": g.pos,
            "success": g.success,
            "dead": g.dead,
            "treasure": g.treasure,
            "potions": g.potions,
            "kills": g.kills,
            "events": events or {},
        }

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.game = Game(self.level, self.max_steps)
        return self.game.features(), self._info()

    def step(self, action):
        if not self.action_space.contains(action):
            raise ValueError(f"action {action!r} is not in {self.action_space}")
        reward, events = self.game.step(int(action), self.np_random)
        g = self.game
        return g.features(), float(reward), g.terminated, g.truncated, self._info(events)

    def action_masks(self) -> np.ndarray:
        """Valid actions in the current state (the sb3-contrib MaskablePPO convention)."""
        return self.game.valid_mask()

    def render(self) -> str | None:
        if self.render_mode != "ansi":
            return None
        g = self.game
        rows = [list(r) for r in self.level.text().splitlines()]
        chars = ".#TPME"
        for r in range(g.height):
            for c in range(g.width):
                rows[r][c] = chars[int(g.grid[r, c])]
        rows[g.pos[0]][g.pos[1]] = "@"
        return "\n".join("".join(r) for r in rows) + f"\nhp={g.hp} t={g.t}\n"
