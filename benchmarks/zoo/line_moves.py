"""What each legal move does in the zoo's line games (tic-tac-toe, Connect Four): the features a
user of such a game would hand pcpg as ``clustering.move_features`` (twenty-eighth session).

One function describes a move of any k-in-a-row game on a grid, with or without gravity, from
the step table alone (the player's own marks, then the opponent's, row by row) in the
vocabulary of these games: whether it wins, blocks a win or (with gravity) lets the opponent win
on top of it; how central its column and row are, whether it is a corner or on the border; how
many of its neighbours are the player's or the opponent's, what it lands on; how many of the
k-long lines through it are still open to the player and how far the player has built them;
its height; and whether it is the player's first move, alone and with the centre, a corner and
the border (an opening). A log without action masks offers every id at every step (the zoo's line games logged none
until the twenty-ninth session): the functions also return which offered moves are playable (a
free cell, a column not full), and pcpg leaves the others out. Like chess's (:mod:`benchmarks.zoo.chess.moves`) they were written
knowing what the styles weigh (the centre, corners, edges, blocking, building next to one's own
or the opponent's pieces, stacking): they show what the framework does when a game's author says
what a move does, not what an unseen game gives.

    clustering.move_features: "benchmarks.zoo.line_moves:tictactoe"
    clustering.move_features: "benchmarks.zoo.line_moves:connect_four"
"""

from __future__ import annotations

import numpy as np

NAMES = (
    "wins", "blocks", "gives_win_above", "column_central", "row_central", "corner", "border",
    "own_near", "theirs_near", "on_own", "on_theirs", "open_lines", "built", "height",
    "first", "first_central", "first_corner", "first_border",
)  # fmt: skip
DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))


def tictactoe(state: np.ndarray, legal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tic-tac-toe's offered cells (id = row * 3 + column) on its 18 numbers, and which are free
    (a log without action masks offers every cell)."""
    board = _board(state, 3, 3)
    cells = [(int(c) // 3, int(c) % 3) for c in legal]
    return _described(board, cells, 3, False)


def connect_four(state: np.ndarray, legal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Connect Four's offered columns on its 84 numbers (rows from the top): each move is the
    cell its piece lands on; a full column is no move (where a log has no action mask)."""
    board = _board(state, 6, 7)
    rows = [int(np.nonzero(board[:, c] == 0)[0].max(initial=0)) for c in legal]
    return _described(board, [(r, int(c)) for r, c in zip(rows, legal, strict=True)], 4, True)


def _described(board: np.ndarray, cells, k: int, gravity: bool) -> tuple[np.ndarray, np.ndarray]:
    """The features of a move to each of ``cells`` (zeros where it is taken) and which are free."""
    free = np.array([board[r, c] == 0 for r, c in cells], bool)
    rows = [
        _features(board, r, c, k, gravity) if ok else [0.0] * len(NAMES)
        for (r, c), ok in zip(cells, free, strict=True)
    ]
    return np.array(rows, dtype=np.float64).reshape(len(cells), len(NAMES)), free


def _board(state: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """(rows, cols): 0 empty, 1 the player's, 2 the opponent's."""
    cells = rows * cols
    own = state[:cells].reshape(rows, cols) > 0.5
    theirs = state[cells : 2 * cells].reshape(rows, cols) > 0.5
    return own + 2 * theirs


def _features(board: np.ndarray, r: int, c: int, k: int, gravity: bool) -> list[float]:
    """A move to the free cell (r, c)."""
    rows, cols = board.shape
    corner = r in (0, rows - 1) and c in (0, cols - 1)
    border = not corner and (r in (0, rows - 1) or c in (0, cols - 1))
    near = board[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2]
    below = board[r + 1, c] if r + 1 < rows else 0
    gives = 0.0
    if gravity and r > 0:
        board[r, c] = 1
        gives = float(_wins(board, r - 1, c, 2, k))
        board[r, c] = 0
    open_lines = [values for values, _ in _lines(board, r, c, k) if 2 not in values]
    first = float(not (board == 1).any())
    column = 1.0 - abs(c - (cols - 1) / 2) / ((cols - 1) / 2)
    row = 1.0 - abs(r - (rows - 1) / 2) / ((rows - 1) / 2)
    return [
        float(_wins(board, r, c, 1, k)),
        float(_wins(board, r, c, 2, k)),
        gives,
        column,
        row,
        float(corner),
        float(border),
        float((near == 1).sum()),
        float((near == 2).sum()),
        float(below == 1),
        float(below == 2),
        float(len(open_lines)),
        float(sum(values.count(1) for values in open_lines)),
        (rows - 1 - r) / max(rows - 1, 1),
        first,
        first * (column + row) / 2,
        first * corner,
        first * border,
    ]


def _wins(board: np.ndarray, r: int, c: int, who: int, k: int) -> bool:
    """Whether ``who`` placing at (r, c) makes k in a line."""
    return any(
        all(v == who or cell == (r, c) for v, cell in zip(values, cells, strict=True))
        for values, cells in _lines(board, r, c, k)
    )


def _lines(board: np.ndarray, r: int, c: int, k: int):
    """Every k-long line of cells through (r, c) that fits on the board: (its values, its cells)."""
    rows, cols = board.shape
    for dr, dc in DIRECTIONS:
        for back in range(k):
            cells = [(r + (i - back) * dr, c + (i - back) * dc) for i in range(k)]
            if all(0 <= y < rows and 0 <= x < cols for y, x in cells):
                yield [int(board[y, x]) for y, x in cells], cells


tictactoe.names = connect_four.names = NAMES  # what pcpg's style_weights table calls each
