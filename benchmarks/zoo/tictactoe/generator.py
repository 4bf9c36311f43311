"""Tic-tac-toe (PettingZoo ``tictactoe_v3``): four styles that differ in opening and tie-breaking.

The styled player takes a seat drawn per episode (X or O) and faces an opponent drawn per episode
(uniform random over the free cells, or a one-ply player that wins when it can, blocks an immediate
threat, and otherwise plays at random). A state is the styled player's observation flattened (18
numbers: its own marks, then the opponent's, row by row); actions are the nine cells (row * 3 +
column), only free ones (the env's action mask). Only the styled player's moves are recorded (the
state before each, then the final state); the reward is +1 / 0 / -1 on its last move. Every style
wins when it can and blocks an immediate threat (almost always); they differ in the opening move
and in how they break the remaining ties, with preferences drawn per episode around their centre
and a small chance of a random free cell.
"""

from __future__ import annotations

import numpy as np
from pettingzoo.classic import tictactoe_v3

from benchmarks.zoo.board_games import opponent, play_two_player
from benchmarks.zoo.common import Episode, Game

LINES = ((0, 1, 2), (3, 4, 5), (6, 7, 8), (0, 3, 6), (1, 4, 7), (2, 5, 8), (0, 4, 8), (2, 4, 6))
CENTRE, CORNERS, EDGES = (4,), (0, 2, 6, 8), (1, 3, 5, 7)
STYLES = (
    "centre opener, corners on ties",
    "corner opener, corners on ties",
    "edge opener, centre then edges on ties",
    "line builder (most open lines)",
)


def _cell_weights(cells: tuple[int, ...]) -> np.ndarray:
    w = np.zeros(9)
    w[list(cells)] = 1.0
    return w


def _completing(board: np.ndarray, legal: list[int], who: int) -> list[int]:
    """The free cells where ``who`` would complete a line (board: 0 empty, 1 mine, 2 theirs)."""
    out = []
    for c in legal:
        for line in LINES:
            if c in line and sum(board[i] == who for i in line) == 2:
                out.append(c)
                break
    return out


def _open_lines(board: np.ndarray, cell: int) -> int:
    """How many lines through ``cell`` hold none of the opponent's marks."""
    return sum(all(board[i] != 2 for i in line) for line in LINES if cell in line)


def _styled(style: int, rng: np.random.Generator):
    opening = (CENTRE, CORNERS, EDGES, CENTRE + CORNERS)[style]
    ties = (
        0.6 * _cell_weights(CORNERS) + 0.3 * _cell_weights(CENTRE),
        _cell_weights(CORNERS) + 0.2 * _cell_weights(CENTRE),
        0.5 * _cell_weights(EDGES) + _cell_weights(CENTRE),
        np.zeros(9),
    )[style] * rng.normal(1.0, 0.2) + rng.normal(0.0, 0.15, 9)
    w_lines = (0.1, 0.1, 0.2, 0.5)[style] * rng.normal(1.0, 0.2)
    block, eps = 0.95 + rng.normal(0.0, 0.02), 0.05

    def policy(board: np.ndarray, legal: list[int]) -> int:
        if rng.random() < eps:
            return int(rng.choice(legal))
        if not (board == 1).any():  # its first move
            free = [c for c in opening if c in legal]
            if free:
                return int(rng.choice(free))
        win = _completing(board, legal, 1)
        if win:
            return win[0]
        threats = _completing(board, legal, 2)
        if threats and rng.random() < block:
            return threats[0]
        scores = [ties[c] + w_lines * _open_lines(board, c) + rng.normal(0.0, 0.1) for c in legal]
        return legal[int(np.argmax(scores))]

    return policy


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    return play_two_player(
        tictactoe_v3.env(),
        seed,
        rng,
        lambda r: _styled(style, r),
        lambda r: opponent(r, _completing),
        lambda p: (p[:, :, 0] + 2 * p[:, :, 1]).reshape(-1),
        masks=True,
    )


GAME = Game(
    name="tictactoe",
    package="pettingzoo[classic] (tictactoe_v3)",
    kinds=("unequal style counts", "a few steps", "two-player board game"),
    styles=STYLES,
    counts=(200, 120, 80, 50),
    ci_counts=(50, 30, 20, 12),
    n_actions=9,
    play=play,
)
