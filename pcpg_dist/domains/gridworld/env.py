"""GridWorld as a Gymnasium environment (the tabular form in :mod:`gridworld` is the fast path)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from pcpg_dist.domains.gridworld.layout import N_ACTIONS, Layout


class GridWorldEnv(gym.Env):
    """PCPG's GridWorld.

    ## Action Space
    ``Discrete(4)``: 0 up, 1 right, 2 down, 3 left. A move into a wall or off the grid is
    invalid: :meth:`action_masks` says which are valid; an invalid action leaves the state
    unchanged, gives no reward and sets ``info["invalid_action"]``.

    ## Observation Space
    ``MultiDiscrete([W, H, 2, 2])``: (x, y, b1, b2), b1/b2 = bonus B1/B2 already visited.

    ## Reward
    Table 1 of the paper for reward function R1..R4 (``reward_index`` 0..3): 100 on reaching G,
    50 on the first visit of B1 (R2, R4) and of B2 (R3, R4).

    ## Episode End
    Terminated on G (success) or a trap (failure); truncated after ``max_steps`` steps (failure).

    ## Arguments
    ``layout``: a :class:`Layout`; ``reward_index``: 0..3; ``max_steps``: episode cap (100).
    """

    metadata = {"render_modes": ["ansi"]}

    def __init__(
        self,
        layout: Layout,
        reward_index: int = 0,
        max_steps: int = 100,
        render_mode: str | None = None,
    ) -> None:
        if reward_index not in range(4):
            raise ValueError(f"reward_index must be 0..3 (R1..R4), got {reward_index}")
        self.layout, self.reward_index, self.max_steps = layout, reward_index, max_steps
        self.render_mode = render_mode
        self._t = layout.tables
        self.action_space = spaces.Discrete(N_ACTIONS)
        self.observation_space = spaces.MultiDiscrete([layout.width, layout.height, 2, 2])
        self._s = self._t.start
        self._steps = 0

    def _obs(self) -> np.ndarray:
        return self._t.features[self._s].astype(np.int64)

    def action_masks(self) -> np.ndarray:
        return self._t.valid[self._s].copy()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self._s, self._steps = self._t.start, 0
        return self._obs(), {"action_mask": self.action_masks()}

    def step(self, action):
        a = int(action)
        info: dict[str, Any] = {}
        reward = 0.0
        if self._t.valid[self._s, a]:
            reward = float(self._t.reward[self.reward_index, self._s, a])
            self._s = int(self._t.next_state[self._s, a])
        else:
            info["invalid_action"] = True
        self._steps += 1
        terminated = bool(self._t.terminal[self._s])
        truncated = not terminated and self._steps >= self.max_steps
        info["success"] = bool(self._t.goal[self._s])
        info["action_mask"] = self.action_masks()
        return self._obs(), reward, terminated, truncated, info

    def render(self) -> str | None:
        if self.render_mode != "ansi":
            return None
        x, y = (int(v) for v in self._t.features[self._s, :2])
        rows = [list(r) for r in self.layout.grid]
        rows[y][x] = "@"
        return "\n".join("".join(r) for r in rows) + "\n"
