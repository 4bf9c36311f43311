"""Goofspiel (OpenSpiel ``goofspiel``, 8 cards): four bidding styles against an opponent drawn per
episode, written after every design choice of the clusterers (a blind game).

Each round a prize card (1-8) is turned up in an order drawn anew every episode (a different task
each time); both players bid one card of their own 1-8 at once, the higher bid takes the prize
(a tie discards it), and a card bid is gone. An episode is one game of 8 rounds. A state is the
styled player's observation tensor (114 numbers: the prize, the prizes left, both scores, its
hand, the win sequence); an action is the card bid (action i bids card i + 1; only cards still
in hand are legal). The reward of a round is the prize won, minus the prize lost. The opponent is
uniform random over its hand, or bids the prize's value plus noise, one or the other per episode.
Per-episode noise: each style's thresholds are drawn, and it bids a random card of its hand with
a small probability.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pyspiel

from benchmarks.zoo.common import Episode, Game

CARDS = 8
GAME_ = pyspiel.load_game(
    "goofspiel",
    {"num_cards": CARDS, "imp_info": True, "points_order": "random",
     "returns_type": "point_difference"},
)  # fmt: skip
STYLES = (
    "matcher: bids the card nearest the prize",
    "sniper: its highest card on the top prizes, its lowest on the rest",
    "one-up: the smallest card above the prize",
    "patient: throws its lowest cards first, then bids the prize plus two",
)


def _nearest(hand: list[int], value: float) -> int:
    return min(hand, key=lambda c: (abs(c - value), c))


def _policy(style: int, rng: np.random.Generator) -> Callable[[int, list[int], int], int]:
    """``bid(prize, hand, round)`` -> card, for one episode of ``style``."""
    if style == 0:
        shift = rng.choice((0.0, 0.0, 0.5))
        return lambda prize, hand, r: _nearest(hand, prize + shift)
    if style == 1:
        top = rng.integers(5, 8)  # prizes from top up are worth its highest card
        return lambda prize, hand, r: max(hand) if prize >= top else min(hand)
    if style == 2:

        def one_up(prize, hand, r):
            above = [c for c in hand if c > prize]
            return min(above) if above else min(hand)

        return one_up
    wait = rng.integers(2, 4)
    return lambda prize, hand, r: min(hand) if r < wait else _nearest(hand, prize + 2)


def _opponent(rng: np.random.Generator) -> Callable[[int, list[int]], int]:
    if rng.random() < 0.5:
        return lambda prize, hand: int(rng.choice(hand))
    return lambda prize, hand: _nearest(hand, prize + rng.normal(0.0, 1.5))


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    bid, opponent, eps = _policy(style, rng), _opponent(rng), rng.uniform(0.03, 0.08)
    state = GAME_.new_initial_state()
    states, actions, rewards, valid = [], [], [], []
    while not state.is_terminal():
        if state.is_chance_node():
            outcomes = [o for o, _ in state.chance_outcomes()]
            state.apply_action(int(rng.choice(outcomes)))
            continue
        prize = int(np.argmax(state.observation_tensor(0)[:CARDS])) + 1
        hand = [a + 1 for a in state.legal_actions(0)]
        other = [a + 1 for a in state.legal_actions(1)]
        mine = int(rng.choice(hand)) if rng.random() < eps else bid(prize, hand, len(actions))
        theirs = opponent(prize, other)
        states.append(state.observation_tensor(0))
        valid.append(np.isin(np.arange(CARDS), state.legal_actions(0)))
        actions.append(mine - 1)
        rewards.append(float(prize * np.sign(mine - theirs)))
        state.apply_actions([mine - 1, theirs - 1])
    states.append(state.observation_tensor(0))
    return Episode(np.array(states), np.array(actions), np.array(rewards), np.array(valid))


GAME = Game(
    name="goofspiel",
    package="open_spiel (goofspiel, 8 cards)",
    kinds=("a different task every episode", "a few steps", "simultaneous-move card game"),
    styles=STYLES,
    counts=(130, 110, 90, 70),
    ci_counts=(26, 22, 18, 14),
    n_actions=CARDS,
    play=play,
    held_out=True,
    blind=True,
)
