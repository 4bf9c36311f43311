"""What every domain provides, and the policy signature used for rollouts.

A domain module says: its state width, number of actions, how to generate or load trajectories
(as a :class:`~pcpg_dist.dataset.Dataset`), and, where it can simulate, how to roll a policy out.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: A batched policy: ``(states (B, d) float32, valid (B, n_actions) bool, rng) -> actions (B,) int``.
#: It must only return valid actions. Rollouts of B episodes call it once per step for the live ones.
Policy = Callable[[np.ndarray, np.ndarray, np.random.Generator], np.ndarray]


def random_policy(states: np.ndarray, valid: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Uniform choice among the valid actions of each state."""
    u = rng.random(valid.shape) * valid
    return np.argmax(u, axis=1)
