"""Othello (OpenSpiel ``othello``): four one-ply styles against an opponent drawn per episode,
written after every design choice of the clusterers (a blind game).

An 8 x 8 board; a move places a disc that flips the opponent's discs it brackets, and a side
without a legal move passes. The styled player takes a seat (black, who moves first, or white)
drawn per episode and faces an opponent drawn per episode: uniform random over its legal moves,
or a greedy player that flips the most discs (each move's count plus N(0, 1.5) noise). A state is
the styled player's observation tensor (192 numbers: three 8 x 8 planes, row by row: the empty
squares, its discs, the opponent's); an action is OpenSpiel's id (row * 8 + column, 64 = pass),
only the legal ones (logged as ``valid``; a forced pass is a decision too). Only the styled
player's decisions are recorded (the state before each, then the final state); the reward is 0
but on its last move, which gets the result (+1 win, 0 draw, -1 loss).

Every style weighs what each legal move does on the board (discs flipped, corners, the squares
next to an empty corner, edges, the opponent's and its own mobility afterwards, frontier discs,
stable edge discs, whether it hands the opponent a corner), with weights drawn per episode around
its centre (each times N(1, 0.2)), a little score noise, and 3-8 % random legal moves: the
maximizer flips as many discs as it can, the mobility player starves the opponent of moves, the
edge player takes edges and stable discs and plays outward, the quiet player makes few, inner
flips that leave no frontier. Each takes corners and shuns handing them over.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pyspiel

from benchmarks.zoo.common import Episode, Game

GAME_ = pyspiel.load_game("othello")
PASS = 64
N_ACTIONS = 65
STYLES = (
    "maximizer: flips the most discs",
    "mobility player: leaves the opponent the fewest moves",
    "edge player: edges and stable discs, playing outward",
    "quiet player: few, inner flips that make no frontier",
)

FULL = (1 << 64) - 1
NOT_A = FULL ^ sum(1 << (r * 8) for r in range(8))  # not column 0
NOT_H = FULL ^ sum(1 << (r * 8 + 7) for r in range(8))  # not column 7
EDGES = sum(1 << (r * 8 + c) for r in range(8) for c in range(8) if r in (0, 7) or c in (0, 7))
#: corner -> (its X-square, its two C-squares, the two edge walks from it)
CORNERS = {
    0: (9, (1, 8), (range(0, 8), range(0, 64, 8))),
    7: (14, (6, 15), (range(7, -1, -1), range(7, 64, 8))),
    56: (49, (48, 57), (range(56, 64), range(56, -1, -8))),
    63: (54, (55, 62), (range(63, 55, -1), range(63, -1, -8))),
}
CORNER_BITS = sum(1 << c for c in CORNERS)
#: each square's ring from the centre: 0 for the four centre squares, 3 on the edge
RING = [max(abs(2 * (i // 8) - 7), abs(2 * (i % 8) - 7)) // 2 for i in range(64)]

#: per style: weights of (discs flipped, a corner, an X-square by an empty corner, a C-square by
#: an empty corner, an edge, the opponent's moves after, its own moves after, new frontier discs,
#: the move's ring from the centre, its stable edge discs, handing the opponent a corner)
CENTRES = np.array(
    [
        [1.0, 4.0, -2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.2, -3.0],
        [-0.1, 5.0, -4.0, -1.0, 0.0, -1.0, 0.4, 0.0, 0.0, 0.2, -5.0],
        [0.0, 6.0, -3.0, 0.0, 3.0, 0.0, 0.0, 0.0, 0.4, 1.0, -4.0],
        [-0.5, 4.0, -3.0, -1.5, -1.0, 0.0, 0.0, -0.8, -0.6, 0.2, -4.0],
    ]
)


def _shift(b: int, d: int) -> int:
    """The bitboard ``b`` moved one square in direction ``d`` (0-7), off-board bits dropped."""
    if d == 0:
        return (b << 1) & NOT_A  # east
    if d == 1:
        return b >> 1 & NOT_H  # west
    if d == 2:
        return (b << 8) & FULL  # south
    if d == 3:
        return b >> 8  # north
    if d == 4:
        return (b << 9) & NOT_A & FULL  # south-east
    if d == 5:
        return (b << 7) & NOT_H & FULL  # south-west
    if d == 6:
        return b >> 7 & NOT_A  # north-east
    return b >> 9 & NOT_H  # north-west


def moves_of(me: int, opp: int) -> int:
    """The squares where ``me`` may play (a bitboard)."""
    empty, out = FULL ^ (me | opp), 0
    for d in range(8):
        x = _shift(me, d) & opp
        for _ in range(5):
            x |= _shift(x, d) & opp
        out |= _shift(x, d) & empty
    return out


def flips_of(me: int, opp: int, square: int) -> int:
    """The discs of ``opp`` that ``me`` playing ``square`` flips (a bitboard)."""
    out = 0
    for d in range(8):
        run, y = 0, _shift(1 << square, d)
        while y & opp:
            run |= y
            y = _shift(y, d)
        if y & me:
            out |= run
    return out


def _frontier(me: int, opp: int) -> int:
    """How many of ``me``'s discs touch an empty square."""
    empty, near = FULL ^ (me | opp), 0
    for d in range(8):
        near |= _shift(empty, d)
    return (near & me).bit_count()


def _stable(me: int) -> int:
    """``me``'s edge discs in unbroken runs from a corner it holds."""
    seen = 0
    for walks in (w for *_, w in CORNERS.values()):
        for walk in walks:
            for sq in walk:
                if not me >> sq & 1:
                    break
                seen |= 1 << sq
    return seen.bit_count()


def features(me: int, opp: int, square: int) -> np.ndarray:
    """The eleven things the styles weigh, of ``me`` playing ``square`` (see :data:`CENTRES`)."""
    flipped = flips_of(me, opp, square)
    mine, theirs = me | flipped | 1 << square, opp ^ flipped
    empty = FULL ^ (me | opp)
    x_sq = any(square == x and empty >> c & 1 for c, (x, _, _) in CORNERS.items())
    c_sq = any(square in cs and empty >> c & 1 for c, (_, cs, _) in CORNERS.items())
    replies = moves_of(theirs, mine)
    return np.array(
        [
            flipped.bit_count(),
            float(square in CORNERS),
            float(x_sq),
            float(c_sq),
            float(bool(EDGES >> square & 1) and square not in CORNERS),
            replies.bit_count(),
            moves_of(mine, theirs).bit_count(),
            _frontier(mine, theirs) - _frontier(me, opp),
            RING[square],
            _stable(mine) - _stable(me),
            float(bool(replies & CORNER_BITS)),
        ]
    )


def _boards(state, player: int) -> tuple[np.ndarray, int, int]:
    """``player``'s observation tensor, and its discs and the opponent's as bitboards."""
    obs = np.asarray(state.observation_tensor(player), np.float32)
    bits = np.packbits(obs[64:].astype(bool), bitorder="little").view("<u8")
    return obs, int(bits[0]), int(bits[1])


#: a player: (its discs, the opponent's, its legal action ids) -> action id
Player = Callable[[int, int, list[int]], int]


def _styled(style: int, rng: np.random.Generator) -> Player:
    weights = CENTRES[style] * rng.normal(1.0, 0.2, CENTRES.shape[1])
    eps = rng.uniform(0.03, 0.08)

    def policy(me: int, opp: int, legal: list[int]) -> int:
        if legal == [PASS] or rng.random() < eps:
            return int(rng.choice(legal))
        scores = [weights @ features(me, opp, a) + rng.normal(0.0, 0.1) for a in legal]
        return legal[int(np.argmax(scores))]

    return policy


def _opponent(rng: np.random.Generator) -> Player:
    greedy = rng.random() < 0.5

    def policy(me: int, opp: int, legal: list[int]) -> int:
        if not greedy or legal == [PASS]:
            return int(rng.choice(legal))
        gains = [flips_of(me, opp, a).bit_count() + rng.normal(0.0, 1.5) for a in legal]
        return legal[int(np.argmax(gains))]

    return policy


def play_against(styled: Player, rival: Player, rng: np.random.Generator) -> Episode:
    """One game of ``styled`` in a seat drawn from ``rng`` against ``rival``."""
    me = int(rng.integers(2))
    state = GAME_.new_initial_state()
    states, actions, valid = [], [], []
    while not state.is_terminal():
        player, legal = state.current_player(), state.legal_actions()
        obs, mine, theirs = _boards(state, player)
        if player == me:
            action = styled(mine, theirs, legal)
            states.append(obs)
            actions.append(action)
            valid.append(np.isin(np.arange(N_ACTIONS), legal))
        else:
            action = rival(mine, theirs, legal)
        state.apply_action(action)
    states.append(np.asarray(state.observation_tensor(me), np.float32))
    rewards = np.zeros(len(actions))
    rewards[-1] = state.returns()[me]
    return Episode(np.array(states), np.array(actions), rewards, np.array(valid))


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    return play_against(_styled(style, rng), _opponent(rng), rng)


GAME = Game(
    name="othello",
    package="open_spiel (othello)",
    kinds=(
        "two-player board game",
        "a different task (opponent) every episode",
        "many features",
        "masked actions",
        "unequal style counts",
    ),
    styles=STYLES,
    counts=(130, 110, 90, 70),
    ci_counts=(26, 22, 18, 14),
    n_actions=N_ACTIONS,
    play=play,
    held_out=True,
    blind=True,
)
