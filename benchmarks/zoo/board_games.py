"""What the zoo's two-player board games share: the opponent of the line games (half the time a
one-ply player that completes or blocks a line, else random) and the PettingZoo play loop that
records the styled player's turns as an episode."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from benchmarks.zoo.common import Episode

#: a player: (board, legal moves) -> move; the board is whatever the game's ``board_of`` makes
Player = Callable[[object, list[int]], int]


def _planes(planes: np.ndarray) -> np.ndarray:
    """An observation's planes flattened, channel first."""
    return np.moveaxis(planes, 2, 0).reshape(-1)


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
    board_of: Callable[[np.ndarray], object],
    state_of: Callable[[np.ndarray], np.ndarray] = _planes,
    max_moves: int | None = None,
    masks: bool = False,
) -> Episode:
    """One game: the styled player takes a random seat; ``state_of`` its observation planes (by
    default flattened, channel first) before each of its moves and at the end are the states, its
    final reward the return. Each player sees ``board_of(planes)`` and the legal moves. The game
    is cut before the styled player's move ``max_moves`` + 1; with ``masks`` the env's action
    masks of its moves are kept (the step table's ``valid``)."""
    env.reset(seed=seed)
    me = env.agents[int(rng.integers(2))]
    policies = {me: styled(rng)}
    policies.update({a: rival(rng) for a in env.agents if a != me})
    states, actions, valid = [], [], []
    while not any(env.terminations.values()) and not any(env.truncations.values()):
        agent = env.agent_selection
        if agent == me and len(actions) == max_moves:
            break
        obs = env.observe(agent)
        planes, legal = obs["observation"], np.flatnonzero(obs["action_mask"])
        action = int(policies[agent](board_of(planes), [int(c) for c in legal]))
        if agent == me:
            states.append(state_of(planes))
            actions.append(action)
            valid.append(obs["action_mask"].astype(bool))
        env.step(action)
    states.append(state_of(env.observe(me)["observation"]))
    rewards = np.zeros(len(actions))
    rewards[-1] = env.rewards[me]
    env.close()
    return Episode(np.array(states), np.array(actions), rewards, np.array(valid) if masks else None)
