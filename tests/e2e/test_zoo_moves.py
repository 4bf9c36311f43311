"""The zoo's move features say what the games' own rules say: the line games' wins, blocks and
playable cells (``benchmarks.zoo.line_moves``) are the generators', goofspiel's hand and bids
(``benchmarks.zoo.goofspiel.moves``) OpenSpiel's, on played positions."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from benchmarks.zoo import line_moves

SHAPES = {"tictactoe": (3, 3), "connect_four": (6, 7)}


@pytest.mark.parametrize("game", sorted(SHAPES))
def test_line_moves_mark_the_wins_blocks_and_playable_cells_the_game_has(game):
    gen = importlib.import_module(f"benchmarks.zoo.{game}.generator")
    rows, cols = SHAPES[game]
    ids = np.arange(gen.GAME.n_actions)
    col = {name: i for i, name in enumerate(line_moves.NAMES)}
    seen = {"wins": 0, "blocks": 0, "no move": 0}
    for style in range(len(gen.STYLES)):
        for state in gen.play(style, seed=11 + style).states[:-1]:
            cells = rows * cols
            board = state[:cells].reshape(rows, cols) + 2 * state[cells:].reshape(rows, cols)
            board = board.astype(int)
            if game == "tictactoe":
                board, legal = board.reshape(-1), [c for c in ids if board.flat[c] == 0]
            else:
                legal = [c for c in ids if board[0, c] == 0]
            phi, playable = getattr(line_moves, game)(state, ids)
            assert phi.shape == (len(ids), len(line_moves.NAMES))
            assert ids[playable].tolist() == legal
            for name, who in (("wins", 1), ("blocks", 2)):
                marked = {int(c) for c in ids[phi[:, col[name]] == 1]}
                assert marked == set(gen._completing(board, legal, who)), (name, state)
                seen[name] += len(marked)
            seen["no move"] += int((~playable).sum())
    assert min(seen.values()) > 0, seen  # each rule was met on the positions played


def test_goofspiel_moves_read_the_prize_and_the_hand_openspiel_has():
    from benchmarks.zoo.goofspiel import generator as gen
    from benchmarks.zoo.goofspiel import moves

    col = {name: i for i, name in enumerate(moves.NAMES)}
    rng = np.random.default_rng(5)
    one_up = gen._policy(2, rng)
    for _ in range(5):
        state = gen.GAME_.new_initial_state()
        while not state.is_terminal():
            if state.is_chance_node():
                state.apply_action(int(rng.choice([o for o, _ in state.chance_outcomes()])))
                continue
            hand = [a + 1 for a in state.legal_actions(0)]
            prize = int(np.argmax(state.observation_tensor(0)[: gen.CARDS])) + 1
            phi, in_hand = moves.move_features(np.array(state.observation_tensor(0)), np.arange(8))
            assert (np.flatnonzero(in_hand) + 1).tolist() == hand
            assert np.flatnonzero(phi[:, col["lowest"]]).tolist() == [min(hand) - 1]
            assert np.flatnonzero(phi[:, col["highest"]]).tolist() == [max(hand) - 1]
            up = np.flatnonzero(phi[:, col["one_up"]]) + 1
            assert up.tolist() == ([one_up(prize, hand, 0)] if max(hand) > prize else [])
            state.apply_actions([int(rng.choice(hand)) - 1, state.legal_actions(1)[0]])
