"""BC's numba kernel at the legal (row, action) pairs only: the same training as the dense
softmax, for logs with many action ids and few legal at a time (chess: 4,672 ids, 20-40 legal)."""

from __future__ import annotations

import numpy as np
import pytest

from pcpg_dist.config.stages import BCConfig
from pcpg_dist.stages.bc import train_cells
from pcpg_dist.stages.bc.network import layer_sizes, start_vector
from pcpg_dist.stages.bc.numba_engine import output_masks, train_numba
from pcpg_dist.stages.ranking import Cell, CellSpec

N_ACTIONS, LEGAL, D = 96, 6, 8
NEVER = 6  # the last NEVER ids are never legal


def many_action_cell(seed: int, rows: int = 600, key: str = "nc-p1-s0") -> Cell:
    """Rows whose legal moves are LEGAL of N_ACTIONS ids (never the last NEVER); the taken move is the legal one
    nearest a direction the state points at (a function of the state a small MLP can learn),
    with 10 % random legal moves."""
    rng = np.random.default_rng(seed)
    mood = rng.integers(0, 4, rows)
    states = np.eye(D, dtype=np.float32)[mood]
    legal = np.stack([rng.choice(N_ACTIONS - NEVER, LEGAL, replace=False) for _ in range(rows)])
    valid = np.zeros((rows, N_ACTIONS), bool)
    valid[np.arange(rows)[:, None], legal] = True
    rank = np.random.default_rng(123).random((4, N_ACTIONS))  # each mood's move preferences
    best = legal[np.arange(rows), np.argmax(rank[mood[:, None], legal], axis=1)]
    noisy = rng.random(rows) < 0.1
    actions = np.where(noisy, legal[np.arange(rows), rng.integers(0, LEGAL, rows)], best)
    spec = CellSpec(key=key, kind="nc", k=-1, p=1.0, seed=seed)
    mean, std = np.full(D, 0.25, np.float32), np.full(D, 0.5, np.float32)
    return Cell(spec, states, valid, actions.astype(np.int64), np.ones(rows), mean, std)


def train_both(cells, cfg):
    """(dense, pairs): train_numba's (parameters, losses, steps) each way, from the same starts."""
    data = [(c.states, c.valid, c.actions, c.weights) for c in cells]
    sizes = layer_sizes(D, N_ACTIONS, cfg)
    starts = [start_vector(sizes, c, None) for c in cells]
    return [train_numba(cells, data, sizes, cfg, starts, pairs=p) for p in (False, True)]


@pytest.mark.parametrize(
    "cfg",
    [
        BCConfig(epochs=60, stop_tol=0),  # the paper's 3 x 5 tanh
        BCConfig(epochs=60, stop_tol=0, hidden_layers=2, hidden_size=16, activation="relu"),
        BCConfig(epochs=60, stop_tol=0, hidden_layers=0),  # the output layer on the inputs
        BCConfig(epochs=20, stop_tol=0, batch_size=128),  # minibatches: blocks of the pairs
    ],
    ids=["tanh", "relu", "linear", "minibatch"],
)
def test_the_legal_pairs_train_as_the_dense_softmax(cfg):
    cells = [many_action_cell(0), many_action_cell(1, rows=350, key="nc-p1-s1")]
    (dense_p, dense_loss, _), (pair_p, pair_loss, _) = train_both(cells, cfg)
    np.testing.assert_allclose(pair_loss, dense_loss, rtol=1e-4)
    for name, value in dense_p.items():
        np.testing.assert_allclose(pair_p[name], value, atol=2e-4, err_msg=name)
    # the weights of actions never legal in a cell get no gradient: they stay at their start
    never = ~cells[0].valid.any(axis=0)
    assert never.sum() == NEVER
    w = pair_p[f"W{cfg.hidden_layers}"][0]
    start = start_vector(layer_sizes(D, N_ACTIONS, cfg), cells[0], None)
    first = start[-(w.size + N_ACTIONS) : -N_ACTIONS].reshape(w.shape)
    np.testing.assert_array_equal(w[:, never], first[:, never].astype(np.float32))


def test_bc_with_many_actions_learns_the_legal_move_it_is_shown():
    """Through train_cells (which takes the pairs by the rule): the agent picks its style's
    move on held-out rows far above the 1 / 6 a random legal move gets."""
    train, test = many_action_cell(0, rows=1500), many_action_cell(7, rows=400)
    model = train_cells([train], BCConfig())
    pred = model.predict(test.states, test.valid, train.spec.key)
    assert test.valid[np.arange(len(pred)), pred].all()
    clean = test.actions  # 10 % of them random: a perfect clone scores ~0.92 (0.83 here)
    assert (pred == clean).mean() >= 0.75


def test_the_rule_keeps_small_action_spaces_dense_and_a_taken_move_counts_as_legal():
    rng = np.random.default_rng(0)
    small = rng.random((50, 39)) < 0.05
    neg, off, _ = output_masks(small, np.zeros(50, np.int64), None)
    assert neg.shape == (39, 50) and off.size == 0  # 39 actions (Mario's): dense
    many = many_action_cell(0, rows=50)
    neg, off, act = output_masks(many.valid, many.actions, None)
    assert neg.shape == (0, 50) and off.size == 51 and np.all(np.diff(off) == LEGAL)
    half = rng.random((50, N_ACTIONS)) < 0.5  # half of them legal: dense
    assert output_masks(half, np.zeros(50, np.int64), None)[1].size == 0
    masked = many.valid.copy()
    masked[0, many.actions[0]] = False  # a log whose mask disagrees with its taken move
    _, off, act = output_masks(masked, many.actions, True)
    assert many.actions[0] in act[off[0] : off[1]]


def test_the_legal_pairs_give_the_same_numbers_on_one_or_two_threads():
    from pcpg_dist.common.devices import set_threads

    cells = [many_action_cell(s, key=f"nc-p1-s{s}") for s in range(3)]
    cfg = BCConfig(epochs=40, stop_tol=0)
    out = []
    for threads in (1, 2):
        set_threads(threads)
        out.append(train_cells(cells, cfg))
    set_threads(1)
    np.testing.assert_array_equal(out[0].final_loss, out[1].final_loss)


@pytest.mark.parametrize("n_actions", [1, 5, 31, 33, 96])
def test_the_packed_mask_key_finds_the_same_distinct_rows_in_the_same_order(n_actions):
    """dedupe_rows packs the valid masks 32 actions a key column: its rows, order, counts and
    inverse are those of a key with one column per action (ties of state broken by the mask)."""
    from pcpg_dist.stages.cell_rows import dedupe_rows

    rng = np.random.default_rng(n_actions)
    rows = 600
    states = rng.integers(0, 3, (rows, 2)).astype(np.float32)  # few states: many ties
    valid = rng.random((rows, n_actions)) < 0.5
    valid[:, 0] = True
    actions = rng.integers(0, n_actions, rows)
    again = rng.integers(0, rows, 200)  # and some rows twice
    states, valid, actions = (np.concatenate([x, x[again]]) for x in (states, valid, actions))
    rows += 200
    got = dedupe_rows(states, valid, actions, return_inverse=True)
    key = np.concatenate(
        [states.view(np.int32).astype(np.int64), valid.astype(np.int64), actions[:, None]], 1
    )
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    assert len(first) < rows  # some rows repeat
    for mine, want in zip(got[:3], (states[first], valid[first], actions[first]), strict=True):
        np.testing.assert_array_equal(mine, want)
    np.testing.assert_array_equal(got[3], np.bincount(inverse.reshape(-1)))
    np.testing.assert_array_equal(got[4], inverse.reshape(-1))
