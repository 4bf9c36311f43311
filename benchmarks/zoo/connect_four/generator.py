"""Connect Four (PettingZoo ``connect_four_v3``): four strategies in one seat against a fixed opponent.

A 6 x 7 board; the styled player takes a seat drawn per episode (first or second to move) and faces
an opponent drawn per episode (uniform random over the legal columns, or a one-ply player that wins
when it can, blocks an immediate threat, and otherwise plays at random). A state is the styled
player's observation flattened (84 numbers: its own pieces, then the opponent's, row by row from
the top); actions are the seven columns, only legal ones (the env's action mask). Only the styled
player's moves are recorded (the state before each, then the final state); the reward is +1 / 0 / -1
on its last move. Every style takes an immediate win; they differ in blocking and in the column
preferences they build with, each drawn per episode around its centre, plus a small chance of a
random legal move.
"""

from __future__ import annotations

import numpy as np
from pettingzoo.classic import connect_four_v3

from benchmarks.zoo.board_games import opponent, play_two_player
from benchmarks.zoo.common import Episode, Game

ROWS, COLS = 6, 7
STYLES = (
    "centre-first builder",
    "edge player",
    "blocker-first (blocks threats, crowds the opponent)",
    "vertical stacker",
)
CENTRE = np.array([0.0, 1.0, 2.0, 3.0, 2.0, 1.0, 0.0]) / 3.0
EDGE = 1.0 - CENTRE


def _drop_row(board: np.ndarray, col: int) -> int:
    """The row a piece dropped in ``col`` lands on (board: 0 empty, 1 mine, 2 theirs), -1 if full."""
    empty = np.nonzero(board[:, col] == 0)[0]
    return int(empty.max()) if len(empty) else -1


def _wins(board: np.ndarray, row: int, col: int, who: int) -> bool:
    """Whether ``who`` placing at (row, col) makes four in a line."""
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        n = 1
        for sign in (1, -1):
            r, c = row + sign * dr, col + sign * dc
            while 0 <= r < ROWS and 0 <= c < COLS and board[r, c] == who:
                n, r, c = n + 1, r + sign * dr, c + sign * dc
        if n >= 4:
            return True
    return False


def _completing(board: np.ndarray, legal: list[int], who: int) -> list[int]:
    """The legal columns where ``who`` would win at once."""
    return [c for c in legal if _wins(board, _drop_row(board, c), c, who)]


def _neighbours(board: np.ndarray, row: int, col: int, who: int) -> int:
    """How many of the eight cells around (row, col) hold ``who``'s pieces."""
    patch = board[max(row - 1, 0) : row + 2, max(col - 1, 0) : col + 2]
    return int((patch == who).sum())


def _styled(style: int, rng: np.random.Generator):
    """The style's move chooser: wins, blocks with its own probability, then scores the columns."""
    block = (0.9, 0.9, 1.0, 0.85)[style] + rng.normal(0.0, 0.05)
    safe = (0.75, 0.8, 0.95, 0.7)[style] + rng.normal(0.0, 0.05)  # avoids giving a win on top
    pref = (CENTRE, EDGE, CENTRE, CENTRE)[style] * rng.normal(1.0, 0.2) + rng.normal(0.0, 0.1, COLS)
    w_own, w_theirs, w_stack = (
        (0.4, 0.0, 0.0),
        (0.5, 0.0, 0.0),
        (0.1, 0.5, 0.0),
        (0.1, 0.0, 1.5),
    )[style]
    w_own, w_theirs, w_stack = (w * rng.normal(1.0, 0.2) for w in (w_own, w_theirs, w_stack))
    eps = 0.05

    def policy(board: np.ndarray, legal: list[int]) -> int:
        if rng.random() < eps:
            return int(rng.choice(legal))
        win = _completing(board, legal, 1)
        if win:
            return win[0]
        threats = _completing(board, legal, 2)
        if threats and rng.random() < block:
            return threats[0]
        scores = []
        for c in legal:
            r = _drop_row(board, c)
            s = (
                pref[c]
                + w_own * _neighbours(board, r, c, 1)
                + w_theirs * _neighbours(board, r, c, 2)
            )
            s += w_stack * (r + 1 < ROWS and board[r + 1, c] == 1)
            if r > 0 and rng.random() < safe:
                above = board.copy()
                above[r, c] = 1
                s -= 5.0 * _wins(above, r - 1, c, 2)
            scores.append(s + rng.normal(0.0, 0.15))
        return legal[int(np.argmax(scores))]

    return policy


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    return play_two_player(
        connect_four_v3.env(),
        seed,
        rng,
        lambda r: _styled(style, r),
        lambda r: opponent(r, _completing),
        lambda p: p[:, :, 0] + 2 * p[:, :, 1],
        masks=True,
    )


GAME = Game(
    name="connect_four",
    package="pettingzoo[classic] (connect_four_v3)",
    kinds=("many features", "two-player board game", "held out"),
    styles=STYLES,
    counts=(120, 120, 120, 120),
    ci_counts=(30, 30, 30, 30),
    n_actions=COLS,
    play=play,
    held_out=True,
)
