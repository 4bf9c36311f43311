"""Leduc poker (OpenSpiel ``leduc_poker``): four betting styles in one seat against a fixed opponent.

A six-card deck (J, Q, K in two suits), one private card each, a public card after the first of two
betting rounds, at most two raises a round. An episode is a short match of four hands against one
opponent drawn per episode (uniform random over the legal actions, or a simple rule-based player),
the styled player's seat drawn for the first hand and alternating. A state is the acting player's
information-state tensor (30 numbers: seat, private card, public card, the betting sequence of
each round); actions are fold, call/check, raise. Only the styled player's decisions are recorded
(the state before each, then the final state); the reward is its chip result of each hand, on its
last decision of that hand. The styles share one rule (raise above a strength, call a raise above
another, otherwise fold or bluff-raise) with their own thresholds and bluff rate, each drawn per
episode around its centre, plus a small chance of a random legal action: they differ only in a few
decisions of a few-step episode.
"""

from __future__ import annotations

import numpy as np
import pyspiel

from benchmarks.zoo.common import Episode, Game

FOLD, CALL, RAISE = 0, 1, 2
STYLES = (
    "tight-passive",
    "tight-aggressive",
    "loose-passive (calling station)",
    "loose-aggressive (bluffer)",
)
# centres of (raise threshold, call threshold when facing a raise, bluff probability)
CENTRES = ((1.1, 0.45, 0.0), (0.45, 0.45, 0.1), (1.1, -0.1, 0.0), (0.3, 0.0, 0.5))
HANDS = 4  # hands in an episode (a short match against one opponent, seats alternating)
GAME_ = pyspiel.load_game("leduc_poker")


def _strength(tensor: np.ndarray) -> float:
    """Hand strength in about [0, 1.2]: the private card's rank, and whether it pairs the board."""
    rank = int(np.argmax(tensor[2:8])) // 2
    if tensor[8:14].max() == 0:  # first round: J, Q or K
        return (0.1, 0.5, 0.9)[rank]
    public = int(np.argmax(tensor[8:14])) // 2
    if rank == public:
        return 1.2
    return 0.05 + 0.3 * rank + (0.15 if rank > public else 0.0)


def _styled(style: int, rng: np.random.Generator):
    raise_at, call_at, bluff = (
        c + rng.normal(0.0, s) for c, s in zip(CENTRES[style], (0.08, 0.08, 0.04), strict=True)
    )
    eps = 0.03

    def policy(tensor: np.ndarray, legal: list[int]) -> int:
        if rng.random() < eps:
            return int(rng.choice(legal))
        s = _strength(tensor) + rng.normal(0.0, 0.05)
        if s >= raise_at:
            return RAISE if RAISE in legal else CALL
        if FOLD in legal and s < call_at:
            return RAISE if RAISE in legal and rng.random() < bluff else FOLD
        if FOLD not in legal and RAISE in legal and rng.random() < bluff:
            return RAISE
        return CALL

    return policy


def _opponent(rng: np.random.Generator):
    if rng.random() < 0.5:
        return lambda tensor, legal: int(rng.choice(legal))

    def rule_based(tensor: np.ndarray, legal: list[int]) -> int:
        s = _strength(tensor)
        if s >= 0.9 and RAISE in legal:
            return RAISE
        return FOLD if FOLD in legal and s < 0.3 else CALL

    return rule_based


def _hand(
    state, policies, seat: int, rng: np.random.Generator, states: list, actions: list, valid: list
) -> None:
    """Plays one hand to its end, recording the styled player's (``seat``) decisions and
    which actions each allowed."""
    while not state.is_terminal():
        if state.is_chance_node():
            outcomes, probs = zip(*state.chance_outcomes(), strict=True)
            state.apply_action(int(rng.choice(outcomes, p=probs)))
            continue
        player = state.current_player()
        tensor = np.asarray(state.information_state_tensor(player), np.float32)
        action = policies[player == seat](tensor, state.legal_actions())
        if player == seat:
            states.append(tensor)
            actions.append(action)
            valid.append(np.isin(np.arange(3), state.legal_actions()))
        state.apply_action(action)


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    policies = {True: _styled(style, rng), False: _opponent(rng)}
    first = int(rng.integers(2))
    states: list[np.ndarray] = []
    actions: list[int] = []
    rewards: list[float] = []
    valid: list[np.ndarray] = []
    for hand in range(HANDS):
        seat, state = (first + hand) % 2, GAME_.new_initial_state()
        _hand(state, policies, seat, rng, states, actions, valid)
        rewards += [0.0] * (len(actions) - len(rewards))
        rewards[-1] += state.returns()[seat]
    states.append(np.asarray(state.information_state_tensor(seat), np.float32))
    return Episode(np.array(states), np.array(actions), np.array(rewards), np.array(valid))


GAME = Game(
    name="leduc_poker",
    package="open_spiel (leduc_poker)",
    kinds=("styles that differ only in a few decisions", "a few steps", "two-player card game"),
    styles=STYLES,
    counts=(150, 150, 150, 150),
    ci_counts=(40, 40, 40, 40),
    n_actions=3,
    play=play,
)
