"""What each legal Othello move does, from the step table alone: the features an Othello player
would hand pcpg as ``clustering.move_features`` for a game whose move ids (a square, or 64 for
a pass) do not say it.

A state is OpenSpiel's observation tensor of the player to move (192 numbers: the empty squares,
the player's discs, the opponent's, each 8 x 8 row by row); a move id is ``row * 8 + column``,
64 a pass. Each legal move is played out exactly on 64-bit boards (numpy, all of a step's moves
at once) and described in the vocabulary of the game: how many discs it flips, alone and
weighed by how full the board is; where it lands (a corner, an X- or C-square next to an empty
corner, another edge square, how central); what it leaves the opponent (its number of moves,
whether it must pass, how many corners it can take) and the player (its own moves, were it to
move again); how many of the discs it places or turns touch an empty square (frontier); how
many stable discs it gains (a sound lower bound: discs no later move can flip); and whether it
plays into a quadrant with an odd number of empty squares (parity). A pass, legal only when no
square is, has every feature 0. Ids that are not legal moves are reported as not playable.
**Written blind**: chosen as a generic description of Othello moves before any clustering of
the game and without knowing the scripted styles of its log.

    clustering.move_features: "benchmarks.zoo.othello.moves:move_features"
"""

from __future__ import annotations

import numpy as np

NAMES = (
    "flips", "flips_late", "corner", "x_square", "c_square", "edge", "central",
    "opp_mobility", "own_mobility", "opp_passes", "opp_corners", "frontier", "stable_gain",
    "odd_region",
)  # fmt: skip
PASS = 64
U = np.uint64
ALL = U(0xFFFFFFFFFFFFFFFF)
NOT_A, NOT_H = U(0xFEFEFEFEFEFEFEFE), U(0x7F7F7F7F7F7F7F7F)  # not column 0, not column 7
# Directions E, S, SE, SW (a left shift by 1, 8, 9, 7) and their opposites W, N, NW, NE
# (a right shift by the same amounts): direction d's opposite is d + 4 (mod 8).
STEP = np.array([[1], [8], [9], [7]], dtype=U)
MASK_UP = np.array([[NOT_A], [ALL], [NOT_A], [NOT_H]], dtype=U)  # after a left shift
MASK_DOWN = np.array([[NOT_H], [ALL], [NOT_H], [NOT_A]], dtype=U)  # after a right shift
BIT = np.left_shift(U(1), np.arange(64, dtype=U))
CORNERS = {0: 0, 7: 7, 56: 56, 63: 63}
X_SQUARES = {9: 0, 14: 7, 49: 56, 54: 63}  # diagonal neighbour of a corner -> that corner
C_SQUARES = {1: 0, 8: 0, 6: 7, 15: 7, 48: 56, 57: 56, 55: 63, 62: 63}
CORNER_BITS = U(sum(1 << c for c in CORNERS))
QUADRANT = np.array([(s // 8 >= 4) * 2 + (s % 8 >= 4) for s in range(64)])


def _shift(x: np.ndarray) -> np.ndarray:
    """Each row d of ``x`` (8, n) moved one square in direction d (squares falling off the board
    are dropped)."""
    out = np.empty_like(x)
    out[:4] = (x[:4] << STEP) & MASK_UP
    out[4:] = (x[4:] >> STEP) & MASK_DOWN
    return out


def _shift_back(x: np.ndarray) -> np.ndarray:
    """Each row d of ``x`` (8, n) moved one square against direction d: the result holds, at a
    square s, what ``x[d]`` holds at s's neighbour in direction d."""
    out = np.empty_like(x)
    out[:4] = (x[:4] >> STEP) & MASK_DOWN
    out[4:] = (x[4:] << STEP) & MASK_UP
    return out


ON_BOARD_NEXT = _shift_back(np.full((8, 1), ALL, dtype=U))  # squares whose neighbour d exists
WALL = ~ON_BOARD_NEXT  # squares at the board's edge in direction d


def _spread(x: np.ndarray) -> np.ndarray:
    """(8, n): each board of ``x`` (n,) copied once per direction."""
    return np.broadcast_to(x, (8, x.shape[0])).copy()


def _moves(own: np.ndarray, opp: np.ndarray) -> np.ndarray:
    """(n,): the squares where the player with discs ``own`` may place against ``opp``."""
    empty = ~(own | opp)
    run = _shift(_spread(own)) & opp
    for _ in range(5):
        run |= _shift(run) & opp
    return np.bitwise_or.reduce(_shift(run) & empty, axis=0)


def _flips(move: np.ndarray, own: np.ndarray, opp: np.ndarray) -> np.ndarray:
    """(n,): the opponent's discs each placed disc ``move`` (n,) turns over."""
    run = _shift(_spread(move)) & opp
    for _ in range(5):
        run |= _shift(run) & opp
    closed = (_shift(run) & own) != 0
    return np.bitwise_or.reduce(np.where(closed, run, U(0)), axis=0)


def _stable(own: np.ndarray, opp: np.ndarray) -> np.ndarray:
    """(n,): a sound lower bound of ``own``'s stable discs. A disc is stable when on each of the
    four lines through it the line is full, or it touches the board's edge, or its neighbour on
    that line is a stable disc of its own (grown from the corners until nothing changes)."""
    occupied = _spread(own | opp)
    full = occupied.copy()  # the squares from which the board is full up to the edge, per d
    for _ in range(7):
        full = occupied & (WALL | _shift_back(full))
    settled = (full[:4] & full[4:]) | WALL[:4] | WALL[4:]  # per line, whatever the neighbours
    stable = np.zeros_like(own)
    while True:
        near = _shift_back(_spread(stable))
        grown = own & np.bitwise_and.reduce(settled | near[:4] | near[4:], axis=0)
        if np.array_equal(grown, stable):
            return stable
        stable = grown


def _count(x: np.ndarray) -> np.ndarray:
    return np.bitwise_count(x).astype(np.float64)


def _board(state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The player's and the opponent's discs, as (1,) 64-bit boards, and the empty squares (64,)."""
    planes = np.asarray(state, dtype=np.float64).reshape(3, 64) > 0.5
    own = np.bitwise_or.reduce(BIT[planes[1]], initial=U(0))
    opp = np.bitwise_or.reduce(BIT[planes[2]], initial=U(0)) & ~own
    return np.array([own], dtype=U), np.array([opp], dtype=U), ~(planes[1] | planes[2])


def _where(squares: np.ndarray, empty: np.ndarray) -> np.ndarray:
    """(n, 5): corner, X-square and C-square next to an empty corner, edge, centrality (1 on the
    ring around the four centre squares, 0.5 on the next, 0 on the edge)."""
    rows = []
    for s in squares.tolist():
        r, c = divmod(s, 8)
        near_x, near_c = X_SQUARES.get(s), C_SQUARES.get(s)
        rows.append([
            float(s in CORNERS),
            float(near_x is not None and bool(empty[near_x])),
            float(near_c is not None and bool(empty[near_c])),
            float((r in (0, 7) or c in (0, 7)) and s not in CORNERS),
            (3.5 - max(abs(r - 3.5), abs(c - 3.5))) / 2.0,  # 1 next to the centre, 0 edge
        ])  # fmt: skip
    return np.array(rows, dtype=np.float64).reshape(len(rows), 5)


def move_features(state: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(len(ids), 14): what each move of ``ids`` does in the position ``state`` (the mover's
    observation tensor); and which ids are legal moves there."""
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    own, opp, empty = _board(state)
    legal = int(_moves(own, opp)[0])
    placing = np.array([0 <= a < PASS and bool(legal >> int(a) & 1) for a in ids], bool)
    playable = placing | ((ids == PASS) & (legal == 0))
    phi = np.zeros((len(ids), len(NAMES)))
    if not placing.any():
        return phi, playable
    squares = ids[placing]
    move = BIT[squares]
    flips = _flips(move, np.repeat(own, len(move)), np.repeat(opp, len(move)))
    mine, theirs = own | move | flips, opp & ~flips
    n = len(move)
    both = _moves(np.concatenate([theirs, mine]), np.concatenate([mine, theirs]))
    opp_moves, own_moves = both[:n], both[n:]
    stable = _count(_stable(np.concatenate([own, mine]), np.concatenate([opp, theirs])))
    empty_after = ~(mine | theirs)
    by_empty = np.bitwise_or.reduce(_shift(_spread(empty_after)), axis=0)
    filled = 1.0 - empty.sum() / 64.0
    odd = np.bincount(QUADRANT[empty], minlength=4) % 2 == 1
    n_flips = _count(flips)
    phi[placing] = np.column_stack([
        n_flips / 10.0,
        n_flips / 10.0 * filled,
        _where(squares, empty),
        _count(opp_moves) / 10.0,
        _count(own_moves) / 10.0,
        (opp_moves == 0).astype(np.float64),
        _count(opp_moves & CORNER_BITS),
        _count((move | flips) & by_empty) / 10.0,
        (stable[1:] - stable[0]) / 10.0,
        odd[QUADRANT[squares]].astype(np.float64),
    ])  # fmt: skip
    return phi, playable


move_features.names = NAMES  # what pcpg's style_weights table calls each feature
