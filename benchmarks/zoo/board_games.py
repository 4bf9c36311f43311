"""What the zoo's two-player board games share: the opponent (half the time a one-ply player that
completes or blocks a line, else random) and the PettingZoo play loop that records the styled
player's turns as an episode."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from benchmarks.zoo.common import Episode

#: a player: (board, legal moves) -> move
Player = Callable[[np.ndarray, list[int]], int]


def opponent(rng: np.random.Generator, completing: Callable[..., list[int]]) -> Player:
    """Per episode, either a one-ply player (wins, else blocks, where ``completing(board, legal,
    mark)`` finds a move completing ``mark``'s line) or a random one."""
    one_ply = rng.random() < 0.5

    def policy(board: np.ndarray, legal: list[int]) -> int:
        if one_ply:
            forced = completing(board, legal, 1) or completing(board, legal, 2)
            if forced:
                return forced[0]
        return int(rng.choice(legal))

    return policy


def play_two_player(
    env,
    seed: int,
    rng: np.random.Generator,
    styled: Callable[[np.random.Generator], Player],
    rival: Callable[[np.random.Generator], Player],
    board_of: Callable[[np.ndarray], np.ndarray],
) -> Episode:
    """One game: the styled player takes a random seat; its observation planes (flattened, channel
    first) before each of its moves and at the end are the states, its final reward the return."""
    env.reset(seed=seed)
    me = env.agents[int(rng.integers(2))]
    policies = {me: styled(rng)}
    policies.update({a: rival(rng) for a in env.agents if a != me})
    states, actions = [], []
    while not any(env.terminations.values()) and not any(env.truncations.values()):
        agent = env.agent_selection
        obs = env.observe(agent)
        planes, legal = obs["observation"], np.flatnonzero(obs["action_mask"])
        board = board_of(planes[:, :, 0] + 2 * planes[:, :, 1])
        action = int(policies[agent](board, [int(c) for c in legal]))
        if agent == me:
            states.append(np.moveaxis(planes, 2, 0).reshape(-1))
            actions.append(action)
        env.step(action)
    states.append(np.moveaxis(env.observe(me)["observation"], 2, 0).reshape(-1))
    rewards = np.zeros(len(actions))
    rewards[-1] = env.rewards[me]
    env.close()
    return Episode(np.array(states), np.array(actions), rewards)
