"""What each legal chess move does, from the step table alone: the features a chess user would
hand pcpg for a game whose move ids do not say it (twenty-seventh session).

A state (774 numbers, :func:`benchmarks.zoo.chess.generator._state`) is read back into a
python-chess board from the player's side (PettingZoo mirrors black's view, so the player is
always white to move there), and each legal move id into a move of that board
(``chess_utils.action_to_move(board, id, 0)``). Its features are generic chess descriptors, not
the styles' nine: which piece moves, what it takes, whether it checks, castles or promotes, how
far it advances, whether its square is attacked or defended after it, how central it is and how
close to the enemy king it lands. Several of them overlap what the styles weigh (a capture, a
check, a pawn push, castling, the centre): that is the point of giving a clusterer what a move
does, and it is why this reading of blind chess is no longer blind.
"""

from __future__ import annotations

import chess
import numpy as np
from pettingzoo.classic.chess import chess_utils

VALUE = (0, 1, 3, 3, 5, 9, 0)  # by python-chess piece type (1 = pawn .. 6 = king)
NAMES = (
    "pawn", "knight", "bishop", "rook", "queen", "king", "takes", "check", "castles", "promotes",
    "advance", "to_rank", "attacked_after", "defended_after", "central", "near_enemy_king",
    "from_back_rank",
)  # fmt: skip


def board_of(state: np.ndarray) -> chess.Board:
    """The player's position (white to move) from its 774 numbers."""
    planes = state[6:].reshape(12, 8, 8) > 0.5  # [piece, 7 - rank, file]
    if not planes.any():  # the log's first observation of a game white opens is empty
        return chess.Board()
    board = chess.Board(None)
    board.turn = chess.WHITE
    ep = None
    for p in range(12):
        color = chess.WHITE if p < 6 else chess.BLACK
        for row, file in zip(*np.nonzero(planes[p]), strict=True):
            rank = 7 - int(row)
            if p == 6 and rank == 7:  # PettingZoo's en-passant mark: the pawn that just moved two
                rank, ep = 4, chess.square(int(file), 5)
            board.set_piece_at(chess.square(int(file), rank), chess.Piece(p % 6 + 1, color))
    rights = 0
    for i, square in enumerate((chess.H1, chess.A1, chess.H8, chess.A8)):
        if state[i] > 0.5:
            rights |= chess.BB_SQUARES[square]
    board.castling_rights = rights & board.rooks
    board.ep_square = ep
    return board


def _features(board: chess.Board, move: chess.Move) -> list[float]:
    piece = board.piece_at(move.from_square)
    kind = piece.piece_type if piece else chess.PAWN
    captured = board.piece_at(move.to_square)
    takes = VALUE[captured.piece_type] if captured else float(board.is_en_passant(move))
    castles = board.is_castling(move)
    board.push(move)
    check = board.is_check()  # gives_check, without its own push and pop
    attacked = board.is_attacked_by(chess.BLACK, move.to_square)
    defended = board.is_attacked_by(chess.WHITE, move.to_square)
    king = board.king(chess.BLACK)
    board.pop()
    to_rank, to_file = chess.square_rank(move.to_square), chess.square_file(move.to_square)
    near = 0.0 if king is None else 1.0 - chess.square_distance(move.to_square, king) / 7.0
    onehot = [float(kind == t) for t in range(1, 7)]
    return onehot + [
        takes,
        float(check),
        float(castles),
        float(move.promotion is not None),
        (to_rank - chess.square_rank(move.from_square)) / 7.0,
        to_rank / 7.0,
        float(attacked),
        float(defended),
        1.0 - max(abs(to_file - 3.5), abs(to_rank - 3.5)) / 3.5,
        near,
        float(chess.square_rank(move.from_square) == 0),
    ]


def move_features(state: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(len(ids), 17) the features of each move id in ``ids``, legal in ``state``."""
    board = board_of(state)
    if not all(int(a) in chess_utils.actions_to_moves for a in ids):
        chess_utils.legal_moves(board)  # fills PettingZoo's id <-> move tables for this position
    return np.array(
        [_features(board, chess_utils.action_to_move(board, int(a), 0)) for a in ids],
        dtype=np.float64,
    ).reshape(len(ids), len(NAMES))


move_features.names = NAMES  # what pcpg's style_weights table and figure call each feature
