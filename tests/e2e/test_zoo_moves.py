"""The zoo's move features say what the games' own rules say: the line games' wins, blocks and
playable cells (``benchmarks.zoo.line_moves``) are the generators', goofspiel's hand and bids
(``benchmarks.zoo.goofspiel.moves``) and Othello's flips, mobility and squares
(``benchmarks.zoo.othello.moves``) OpenSpiel's, on played positions."""

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


def _othello_owner(state, player):
    """+1 the player's disc, -1 the opponent's, 0 empty (8 x 8), from OpenSpiel's tensor."""
    t = np.array(state.observation_tensor(player)).reshape(3, 8, 8)
    return (t[1] - t[2]).astype(int)


def _othello_check_move(moves, col, state, me, a, row, owner):
    """One legal placement ``a`` of ``state`` against OpenSpiel's own play of it."""
    after = state.clone()
    after.apply_action(int(a))
    new = _othello_owner(after, me)
    changed = new != owner
    assert changed.sum() == round(row[col["flips"]] * 10) + 1, a
    assert new[changed].tolist() == [1] * int(changed.sum())
    empty_after = np.pad(new == 0, 1)
    touches = np.zeros((8, 8), bool)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            touches |= empty_after[1 + dr : 9 + dr, 1 + dc : 9 + dc]
    assert (changed & touches).sum() == round(row[col["frontier"]] * 10)
    mine = moves.move_features(np.array(after.observation_tensor(me)), np.arange(64))[1]
    assert mine.sum() == round(row[col["own_mobility"]] * 10)
    theirs = [] if after.is_terminal() else after.legal_actions()
    theirs = [b for b in theirs if b != moves.PASS]
    assert len(theirs) == round(row[col["opp_mobility"]] * 10)
    assert row[col["opp_passes"]] == float(not theirs)
    assert row[col["opp_corners"]] == len({0, 7, 56, 63} & set(theirs))
    r, c = divmod(int(a), 8)
    assert row[col["corner"]] == float(r in (0, 7) and c in (0, 7))
    assert row[col["edge"]] == float((r in (0, 7)) != (c in (0, 7)))
    corner = {9: (0, 0), 14: (0, 7), 49: (7, 0), 54: (7, 7)}.get(int(a))
    assert row[col["x_square"]] == float(corner is not None and owner[corner] == 0)
    quadrant = owner[r // 4 * 4 : r // 4 * 4 + 4, c // 4 * 4 : c // 4 * 4 + 4]
    assert row[col["odd_region"]] == float((quadrant == 0).sum() % 2)
    assert row[col["stable_gain"]] >= row[col["corner"]] / 10


def test_othello_moves_play_each_move_as_openspiel_does():
    pyspiel = pytest.importorskip("pyspiel")
    from benchmarks.zoo.othello import moves

    assert len(moves.move_features.names) == len(moves.NAMES)
    col = {name: i for i, name in enumerate(moves.NAMES)}
    game = pyspiel.load_game("othello")
    rng = np.random.default_rng(3)
    seen = {"moves": 0, "passes": 0, "corners": 0, "opp_passes": 0, "stable": 0}
    for _ in range(4):
        state, claims = game.new_initial_state(), []  # claims: (player, squares said stable)
        while not state.is_terminal():
            me = state.current_player()
            obs, legal = np.array(state.observation_tensor(me)), state.legal_actions()
            phi, playable = moves.move_features(obs, np.arange(66))  # 65: no move at all
            assert phi.shape == (66, len(moves.NAMES)) and np.isfinite(phi).all()
            assert np.flatnonzero(playable).tolist() == legal
            owner = _othello_owner(state, me)
            for a in legal:
                if a == moves.PASS:
                    assert not phi[a].any()
                    seen["passes"] += 1
                    continue
                _othello_check_move(moves, col, state, me, a, phi[a], owner)
                seen["moves"] += 1
                seen["corners"] += int(phi[a, col["corner"]])
                seen["opp_passes"] += int(phi[a, col["opp_passes"]])
            own, opp, _ = moves._board(obs)
            stable = int(moves._stable(own, opp)[0])
            claims.append((me, [s for s in range(64) if stable >> s & 1]))
            seen["stable"] += len(claims[-1][1])
            forcing = [a for a in legal if phi[a, col["opp_passes"]]]  # to meet passes too
            state.apply_action(int(rng.choice(forcing or legal)))
            for player, squares in claims:  # a disc said stable is never turned over
                assert all(_othello_owner(state, player).flat[s] == 1 for s in squares)
    assert min(seen.values()) > 0, seen  # each rule was met on the positions played


def test_othellos_move_features_written_blind_find_its_styles_without_labels():
    """Othello's features were written without seeing its styles (a blind game): at CI size
    (80 games) the default clusters by them and places every game with its own style, and the
    label-free confidence says so."""
    pytest.importorskip("pyspiel")
    from benchmarks.zoo.check import labelled_dataset
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import cluster, clustering_metrics
    from pcpg_dist.stages.clustering.confidence import stability, verdict_of

    ds = labelled_dataset("othello", True)
    cfg = ClusterConfig(k=4, move_features="benchmarks.zoo.othello.moves:move_features")
    result = cluster(ds, cfg, 0)
    assert result.metrics["auto_chose_choice_mix"] == 1.0
    assert clustering_metrics(ds.styles, result.labels)["accuracy"] == 1.0
    found = stability(ds, cfg, 0, result.labels, cfg.confidence_runs, cfg.confidence_fraction)
    assert verdict_of({**result.metrics, **found}, 4).verdict == "styles found"
