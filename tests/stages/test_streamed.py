"""The streamed stages' block functions: sums over any cut of the rows give the whole log's
answer, k-means from block statistics separates clear groups, the split and the top-p threshold
are what they say, and the stacked BC cells learn a policy and do not disturb each other."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pcpg_dist.common.errors import DataError
from pcpg_dist.stages.streamed import cells as C
from pcpg_dist.stages.streamed import features as F
from pcpg_dist.stages.streamed import kmeans as K
from pcpg_dist.stages.streamed import policy as P
from pcpg_dist.stages.streamed import ranking as R

D, A = 3, 4
STATES = tuple(f"s{j}" for j in range(D))


def steps(rng, n=40):
    """A small step table (dict of columns) with trajectories of 1..9 rows, shuffled."""
    length = rng.integers(1, 10, n)
    rows = int(length.sum())
    batch = {
        "trajectory": np.repeat(np.arange(n) * 7 + 3, length),
        "action": rng.integers(-1, A, rows),
        "reward": rng.normal(size=rows),
        "style": np.repeat(rng.integers(0, 3, n), length),
    }
    batch.update({s: rng.normal(size=rows).astype(np.float32) for s in STATES})
    order = rng.permutation(rows)
    return {k: v[order] for k, v in batch.items()}


def summed_over(blocks):
    """Add per-block partials by trajectory, as the engine's hash aggregation does."""
    parts = [F.step_partials(b, STATES, A) for b in blocks]
    ids = np.unique(np.concatenate([p["trajectory"] for p in parts]))
    out = {"trajectory": ids, "style": np.full(len(ids), -1)}
    for col in F.partial_columns(D, A):
        out[col] = np.zeros(len(ids))
    for p in parts:
        at = np.searchsorted(ids, p["trajectory"])
        for col in F.partial_columns(D, A):
            np.add.at(out[col], at, p[col])
        np.maximum.at(out["style"], at, p["style"])
    return out


def test_features_do_not_depend_on_how_the_rows_are_cut(rng):
    batch = steps(rng)
    whole = F.trajectory_features(summed_over([batch]), D, A)
    for _ in range(5):
        cuts = np.sort(rng.choice(np.arange(1, len(batch["action"])), 6, replace=False))
        blocks = [
            {k: v[lo:hi] for k, v in batch.items()}
            for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(batch["action"])], strict=True)
        ]
        cut = F.trajectory_features(summed_over(blocks), D, A)
        np.testing.assert_array_equal(cut["trajectory"], whole["trajectory"])
        np.testing.assert_allclose(cut["x"], whole["x"], rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(cut["ret"], whole["ret"], atol=1e-9)


def test_features_are_the_trajectory_statistics(rng):
    batch = steps(rng)
    f = F.trajectory_features(summed_over([batch]), D, A)
    i = 5
    tid = f["trajectory"][i]
    mine = batch["trajectory"] == tid
    acted = batch["action"][mine] >= 0
    x = np.stack([batch[s][mine] for s in STATES], 1)
    assert f["length"][i] == acted.sum()
    assert f["ret"][i] == pytest.approx(batch["reward"][mine][acted].sum())
    np.testing.assert_allclose(f["x"][i, 1 + A : 1 + A + D], x.mean(0), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(f["x"][i, 1 + A + D :], x.std(0), rtol=1e-4, atol=1e-5)
    if acted.any():
        freq = np.bincount(batch["action"][mine][acted], minlength=A) / acted.sum()
        np.testing.assert_allclose(f["x"][i, 1 : 1 + A], freq, rtol=1e-6)


@pytest.mark.parametrize(
    ("column", "value", "says"),
    [
        ("action", 9, "actions are 0..3"),
        ("s1", np.nan, "non-finite"),
        ("action", -3, "action -3"),
        ("style", 100_000, "styles are 0..99999 or -1"),
    ],
)
def test_a_bad_block_is_one_line_naming_the_column(rng, column, value, says):
    batch = steps(rng)
    batch[column] = batch[column].astype(
        np.float32 if column.startswith("s") and column != "style" else int
    )
    batch[column][4] = value
    with pytest.raises(DataError, match=says):
        F.step_partials(batch, STATES, A)


def test_string_trajectory_ids_are_refused_in_one_line(rng):
    batch = steps(rng)
    batch["trajectory"] = batch["trajectory"].astype(str)
    with pytest.raises(DataError, match="integer trajectory ids"):
        F.step_partials(batch, STATES, A)


def test_kmeans_from_block_statistics_separates_clear_groups(rng):
    truth = rng.integers(0, 3, 3000)
    x = rng.normal(size=(3000, 5)) + 6.0 * np.eye(3, 5)[truth]
    total = sum(K.moments(b) for b in np.array_split(x, 7))
    mean, scale = K.scaling(total)
    z = (x - mean) / scale
    centres = K.initial_centres(z[rng.permutation(3000)[:500]], 3, seed=0)
    for _ in range(10):
        stats = sum(K.lloyd_stats(b, centres) for b in np.array_split(z, 7))
        centres, inertia, move = K.lloyd_update(centres, stats)
    labels = K.assign(z, centres)
    from sklearn.metrics import adjusted_rand_score

    assert adjusted_rand_score(truth, labels) > 0.99
    assert move < 1e-6
    # the same statistics from other cuts give the same centres
    again = sum(K.lloyd_stats(b, centres) for b in np.array_split(z, 3))
    np.testing.assert_allclose(K.lloyd_update(centres, again)[0], centres, atol=1e-9)


def test_split_is_a_fixed_share_decided_by_id_and_seed():
    ids = np.arange(200_000, dtype=np.int64) * 13
    u = R.uniform(ids, seed=3)
    assert ((u >= 0) & (u < 1)).all()
    assert R.is_test(ids, 3, 0.2).mean() == pytest.approx(0.2, abs=0.005)
    np.testing.assert_array_equal(R.is_test(ids[::-1], 3, 0.2), R.is_test(ids, 3, 0.2)[::-1])
    assert (R.is_test(ids, 3, 0.2) != R.is_test(ids, 4, 0.2)).mean() > 0.2
    assert np.corrcoef(R.uniform(ids, 3, 0), R.uniform(ids, 3, 1))[0, 1] < 0.01


@pytest.mark.parametrize("p", [1.0, 0.5, 0.1, 0.001])
def test_each_group_keeps_exactly_its_top_p_even_with_ties(rng, p):
    # integer returns: most scores are tied, as a count of good actions is
    score = np.r_[rng.integers(0, 30, 5000), rng.normal(10, 3, size=3000)].astype(float)
    group = np.r_[np.zeros(5000, int), np.ones(3000, int)]
    ids = rng.permutation(8000).astype(np.int64)
    blocks = [slice(0, 4000), slice(4000, 8000)]
    span = R.merge_ranges(*(R.score_ranges(score[b], group[b], 2) for b in blocks))
    lo, hi = span[:2], span[2:]
    assert lo.tolist() == [score[:5000].min(), score[5000:].min()]
    assert hi.tolist() == [score[:5000].max(), score[5000:].max()]
    hist = sum(R.score_histogram(score[b], group[b], lo, hi) for b in blocks)
    where, need = R.boundaries(hist, 2, p)
    tie = R.uniform(ids, 0, 3)
    edge = (R.bins_of(score, group, lo, hi) == where[group]) & (where[group] >= 0)
    cut_score, cut_tie = R.exact_cuts(score[edge], tie[edge], group[edge], need)
    kept = R.is_kept(score, tie, cut_score[group], cut_tie[group])
    for g, n in ((0, 5000), (1, 3000)):
        mine = group == g
        assert kept[mine].sum() == max(1, int(np.ceil(p * n)))
        # nothing dropped scores higher than anything kept
        if (~kept[mine]).any():
            assert score[mine][~kept[mine]].max() <= score[mine][kept[mine]].min()


def test_codes_say_which_rows_train_which_cell():
    cluster = np.array([0, 1, 1, 2])
    code = C.code_of(
        cluster,
        test=np.array([False, False, True, False]),
        validation=np.array([True, False, False, False]),
        kept_cluster=[np.ones(4, bool), np.array([True, False, True, True])],
        kept_nc=[np.ones(4, bool), np.array([False, True, True, False])],
    )
    cells = [(0, 0), (1, 0), (1, 1), (C.NC, 0), (C.NC, 1)]
    m = C.membership(code, cells)
    assert m.tolist() == [
        [True, False, False, False],
        [False, True, False, False],
        [False, False, False, False],  # trajectory 1 not kept at p index 1; 2 is held out
        [True, True, False, True],
        [False, True, False, False],
    ]
    assert ((code & C.VALIDATION) != 0).tolist() == [True, False, False, False]


def linear_task(rng, n=6000):
    x = rng.normal(size=(n, 4)).astype(np.float32)
    w = np.array([[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0]], np.float32)
    return x, (x @ w.T).argmax(1)


def train(model, x, y, member, epochs=40):
    opt = torch.optim.Adam(model.parameters(), lr=0.02)
    for _ in range(epochs):
        for lo in range(0, len(y), 1000):
            m = member[:, lo : lo + 1000]
            w = torch.as_tensor(m / np.maximum(m.sum(1), 1)[:, None], dtype=torch.float32)
            loss = P.cell_losses(
                model(torch.as_tensor(x[lo : lo + 1000])), torch.as_tensor(y[lo : lo + 1000]), w
            )
            opt.zero_grad()
            loss.sum().backward()
            opt.step()


def test_a_stacked_cell_learns_a_policy_and_ignores_the_other_cells_rows(rng):
    x, y = linear_task(rng)
    other = rng.integers(0, 3, len(y))  # the second cell learns noise from other rows
    together = P.StackedPolicy(2, 4, 3, 2, 16, "tanh", seed=1)
    member = np.stack([np.arange(len(y)) % 2 == 0, np.arange(len(y)) % 2 == 1])
    yy = np.where(member[0], y, other)
    train(together, x, yy, member)
    alone = P.StackedPolicy(2, 4, 3, 2, 16, "tanh", seed=1)
    train(alone, x, yy, np.stack([member[0], np.zeros(len(y), bool)]))
    test_x, test_y = linear_task(np.random.default_rng(99), 2000)
    with torch.no_grad():
        acc = (together(torch.as_tensor(test_x)).argmax(-1).numpy() == test_y).mean(1)
        solo = (alone(torch.as_tensor(test_x))[0].argmax(-1).numpy() == test_y).mean()
    assert acc[0] > 0.9 and acc[1] < 0.6
    assert solo == pytest.approx(acc[0], abs=0.01)
    np.testing.assert_allclose(together.cell_state(0)[0], alone.cell_state(0)[0], atol=1e-4)


def test_accuracy_counts_match_a_direct_count(rng):
    x, y = linear_task(rng, 70_000)  # more rows than one evaluation pass takes
    model = P.StackedPolicy(3, 4, 3, 1, 8, "relu", seed=0)
    cluster = rng.integers(0, 2, len(y))
    counts = P.accuracy_counts(model, x, y, cluster, 2)
    with torch.no_grad():
        pred = model(torch.as_tensor(x)).argmax(-1).numpy()
    direct = np.array(
        [[(pred[c][cluster == g] == y[cluster == g]).sum() for g in range(2)] for c in range(3)]
    )
    np.testing.assert_array_equal(counts[:6].reshape(3, 2), direct)
    np.testing.assert_array_equal(counts[6:], np.bincount(cluster, minlength=2))


def test_early_stop_keeps_each_cells_best_weights():
    model = P.StackedPolicy(2, 2, 2, 1, 2, "tanh", seed=0)
    stop = P.EarlyStop(2, patience=1)
    stop.update(np.array([1.0, 1.0]), model)
    first = model.cell_state(0)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(1.0)
    stop.update(np.array([2.0, 0.5]), model)  # cell 0 got worse: stopped, keeps epoch 1
    assert stop.done.tolist() == [True, False]
    np.testing.assert_array_equal(stop.best_states[0][0], first[0])
    np.testing.assert_array_equal(stop.best_states[1][0], model.cell_state(1)[0])


def test_an_error_said_in_a_worker_comes_back_as_itself():
    from pcpg_dist.common.errors import ConfigError
    from pcpg_dist.common.errors import said_in_worker as _said_in_worker
    from pcpg_dist.orchestration.streaming.steps import _padded_add

    text = (
        "ray::ReadFiles->MapBatches(step_partials)() (pid=1)\n  File ...\n"
        "pcpg_dist.common.errors.DataError: column 'action': trajectory 3 has action 7; "
        "actions are 0..3 (-1 on a closing row)\n\nThe above exception was the direct cause"
    )
    said = _said_in_worker(text)
    assert isinstance(said, DataError)
    assert (
        str(said)
        == "column 'action': trajectory 3 has action 7; actions are 0..3 (-1 on a closing row)"
    )
    assert isinstance(_said_in_worker("pcpg_dist.common.errors.ConfigError: k"), ConfigError)
    assert _said_in_worker("ValueError: something else") is None
    assert _said_in_worker("pcpg_dist.common.errors.NoSuchError: x") is None
    np.testing.assert_array_equal(_padded_add(np.ones(2), np.ones(5)), [2, 2, 1, 1, 1])
