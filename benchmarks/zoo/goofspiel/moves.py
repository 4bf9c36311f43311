"""What each bid does in goofspiel, from the step table alone: the features a user of a bidding
game would hand pcpg as ``clustering.move_features`` (twenty-eighth session).

A state is OpenSpiel's observation tensor for 8 cards (114 numbers: the prize one-hot, the
prizes left, both players' points one-hot, the player's hand, the win sequence); a move id ``a``
bids card ``a + 1``. Each bid is described against the prize and the hand: how far above the
prize it is, how near the prize and the prize plus two, whether it is the lowest or highest card
in hand or the smallest above the prize, the highest and the lowest weighed by the prize, the
lowest in the first three rounds and the card itself; and which bids are in hand at all (a log
without action masks offers every id, as the zoo's did until the twenty-ninth session: pcpg
leaves the others out). **Written knowing the
styles** (a matcher, a sniper, a one-up bidder, a patient bidder): this reading of the blind game
is no longer blind.

    clustering.move_features: "benchmarks.zoo.goofspiel.moves:move_features"
"""

from __future__ import annotations

import numpy as np

from benchmarks.zoo.goofspiel.generator import CARDS

PRIZE, HAND = slice(0, CARDS), slice(90, 90 + CARDS)  # where the tensor holds them
NAMES = (
    "above_prize", "near_prize", "near_prize_plus_two", "lowest", "highest", "one_up",
    "highest_x_prize", "lowest_x_prize", "lowest_early", "card",
)  # fmt: skip


def move_features(state: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(len(ids), 10): each bid of ``ids`` against the state's prize and hand; and which of them
    are in hand."""
    prize = int(np.argmax(state[PRIZE])) + 1
    hand = [c + 1 for c in np.flatnonzero(state[HAND] > 0.5)]
    in_hand = np.array([int(a) + 1 in hand for a in ids], bool)
    above = [c for c in hand if c > prize]
    early = float(CARDS - len(hand) < 3)
    rows = []
    for a, playable in zip(ids, in_hand, strict=True):
        card = int(a) + 1
        if not playable:
            rows.append([0.0] * len(NAMES))
            continue
        low, high = float(card == min(hand)), float(card == max(hand))
        rows.append([
            (card - prize) / CARDS,
            -abs(card - prize) / CARDS,
            -abs(card - prize - 2) / CARDS,
            low,
            high,
            float(bool(above) and card == min(above)),
            high * prize / CARDS,
            low * prize / CARDS,
            low * early,
            card / CARDS,
        ])  # fmt: skip
    return np.array(rows, dtype=np.float64).reshape(len(ids), len(NAMES)), in_hand


move_features.names = NAMES  # what pcpg's style_weights table calls each feature
