"""Chess (PettingZoo ``chess_v6``): four one-ply styles against a weak opponent, 4,672 masked actions.

The styled player takes a seat drawn per episode and faces an opponent drawn per episode (uniform
random over its legal moves, or a capturer that takes the most valuable piece it can and otherwise
moves at random). A state is the styled player's view of the board (PettingZoo's observation,
which mirrors it for black): the twelve piece planes of the current position (768 numbers: its
pieces, then the opponent's) and the four castling rights, the side and the no-capture clock (six
numbers): 774 in all. Actions are PettingZoo's 8 x 8 x 73 move ids (4,672), only the legal ones
(``valid``, the env's action mask; 20-40 of them in most positions). Only the styled player's
moves are recorded, at most 60 of them; the reward is the game's result (+1 / 0 / -1) on its last
move (0 where the game is cut at 60 moves).

Every style mates in one when it can, takes an undefended piece of higher value than a pawn
when its weights say so, and avoids leaving the moved piece hanging; they differ in what they
prefer among the rest (weights drawn per episode around their centre, and 5 % random legal
moves): the materialist takes material, the attacker gives checks and attacks pieces near the
enemy king, the pawn stormer pushes pawns, the developer brings out its minor pieces, castles and
takes the centre.
"""

from __future__ import annotations

import chess
import numpy as np
from pettingzoo.classic import chess_v6
from pettingzoo.classic.chess import chess_utils

from benchmarks.zoo.board_games import play_two_player
from benchmarks.zoo.common import Episode, Game

STYLES = ("materialist", "attacker", "pawn stormer", "developer")
VALUE = {
    chess.PAWN: 1,
    chess.KNIGHT: 3,
    chess.BISHOP: 3,
    chess.ROOK: 5,
    chess.QUEEN: 9,
    chess.KING: 0,
}
CENTRE = chess.SquareSet([chess.D4, chess.E4, chess.D5, chess.E5])
MOVES = 60
N_ACTIONS = 8 * 8 * 73

#: per style: weights of (captured value, hanging the moved piece, check, pieces attacked near
#: the enemy king, pawn move and its advance, developing a minor piece, castling, the centre,
#: an early queen move)
CENTRES = np.array(
    [
        [3.0, -3.0, 0.3, 0.1, 0.0, 0.2, 0.3, 0.2, 0.0],
        [1.0, -1.5, 2.0, 0.8, 0.0, 0.1, 0.0, 0.1, 0.0],
        [1.0, -1.5, 0.2, 0.0, 1.5, 0.0, 0.0, 0.2, -0.5],
        [1.0, -2.0, 0.2, 0.0, 0.0, 1.5, 2.5, 0.8, -1.5],
    ]
)


def features(board: chess.Board, move: chess.Move, moved_so_far: int) -> np.ndarray:
    """The nine things the styles weigh, of ``move`` by the side to move."""
    piece = board.piece_at(move.from_square)
    captured = board.piece_at(move.to_square)
    taken = VALUE[captured.piece_type] if captured else (1 if board.is_en_passant(move) else 0)
    check = board.gives_check(move)
    castle = board.is_castling(move)
    me = board.turn
    board.push(move)
    hanging = 0.0
    if board.is_attacked_by(not me, move.to_square) and not board.is_attacked_by(
        me, move.to_square
    ):
        hanging = VALUE[piece.piece_type]
    king = board.king(not me)
    near = 0
    if king is not None:
        ring = chess.SquareSet(chess.BB_KING_ATTACKS[king]) | chess.SquareSet([king])
        near = sum(1 for sq in board.attacks(move.to_square) if sq in ring)
    board.pop()
    pawn = piece.piece_type == chess.PAWN
    advance = (
        chess.square_rank(move.to_square)
        if me == chess.WHITE
        else 7 - chess.square_rank(move.to_square)
    )
    back = 0 if me == chess.WHITE else 7
    develops = (
        piece.piece_type in (chess.KNIGHT, chess.BISHOP)
        and chess.square_rank(move.from_square) == back
    )
    early_queen = piece.piece_type == chess.QUEEN and moved_so_far < 10
    return np.array(
        [
            taken,
            hanging,
            float(check),
            float(near),
            float(pawn) * (1.0 + advance / 7.0),
            float(develops),
            float(castle),
            float(move.to_square in CENTRE),
            float(early_queen),
        ]
    )


def _mates(board: chess.Board, move: chess.Move) -> bool:
    if not board.gives_check(move):
        return False
    board.push(move)
    mate = board.is_checkmate()
    board.pop()
    return mate


def _styled(style: int, rng: np.random.Generator):
    weights = CENTRES[style] * rng.normal(1.0, 0.2, CENTRES.shape[1])
    eps = 0.05

    def policy(board: chess.Board, moves: dict[int, chess.Move], moved: int) -> int:
        ids = list(moves)
        if rng.random() < eps:
            return int(rng.choice(ids))
        for a in ids:
            if _mates(board, moves[a]):
                return a
        scores = [weights @ features(board, moves[a], moved) + rng.normal(0.0, 0.1) for a in ids]
        return ids[int(np.argmax(scores))]

    return policy


def _rival(rng: np.random.Generator):
    capturer = rng.random() < 0.5

    def policy(board: chess.Board, moves: dict[int, chess.Move], moved: int) -> int:
        ids = list(moves)
        if capturer:
            gains = [
                VALUE[p.piece_type] if (p := board.piece_at(moves[a].to_square)) else 0 for a in ids
            ]
            if max(gains) > 0:
                return ids[int(np.argmax(gains))]
        return int(rng.choice(ids))

    return policy


def _moving(policy):
    """A board-game :data:`~benchmarks.zoo.board_games.Player` from a chess policy of (board,
    {move id: chess.Move}, the side's moves so far): PettingZoo's ids read for the side to move."""

    def player(board: chess.Board, legal: list[int]) -> int:
        side = int(board.turn == chess.BLACK)  # PettingZoo mirrors black's ids
        moves = {a: chess_utils.action_to_move(board, a, side) for a in legal}
        return policy(board, moves, board.fullmove_number - 1)

    return player


def _state(obs: np.ndarray) -> np.ndarray:
    """PettingZoo's (8, 8, 111) observation as 774 numbers: six rule planes as one number each
    (castling rights, side, no-capture clock), then the current position's twelve piece planes."""
    rules = obs[0, 0, :6].astype(np.float32)
    rules[5] = obs[:, :, 5].sum()  # the clock is one square's count
    return np.concatenate([rules, np.moveaxis(obs[:, :, 7:19], 2, 0).reshape(-1)])


def play(style: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    env = chess_v6.env()
    return play_two_player(
        env,
        seed,
        rng,
        lambda r: _moving(_styled(style, r)),
        lambda r: _moving(_rival(r)),
        lambda planes: env.unwrapped.board,
        _state,
        max_moves=MOVES,
        masks=True,
    )


GAME = Game(
    name="chess",
    package="pettingzoo[classic] (chess_v6)",
    kinds=(
        "many features",
        "thousands of masked actions",
        "two-player board game",
        "a different task (opponent) every episode",
        "unequal style counts",
    ),
    styles=STYLES,
    counts=(140, 110, 90, 60),
    ci_counts=(28, 22, 18, 12),
    n_actions=N_ACTIONS,
    play=play,
    held_out=True,
    blind=True,
)
