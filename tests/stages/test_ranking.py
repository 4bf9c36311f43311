"""Step B: Performance (Eq. 3), splits, top-p thresholding, corruption and cell planning."""

from __future__ import annotations

import numpy as np
import pytest
from bc_toy import make_dataset
from pydantic import ValidationError

from pcpg_dist.common.errors import DataError
from pcpg_dist.dataset import Dataset
from pcpg_dist.domains.defaults import performance, split_trajectories
from pcpg_dist.stages.ranking import (
    RankConfig,
    cell_subsets,
    corrupt_labels,
    n_kept,
    plan_cells,
    threshold,
    top_p,
)


@pytest.fixture(scope="module")
def toy() -> Dataset:
    return make_dataset(60, seed=3)


def _lined(lengths, success) -> Dataset:
    trajs = [
        {
            "states": np.zeros((n, 1)),
            "actions": np.zeros(n - 1, int),
            "valid": np.ones(n, int),
            "rewards": np.zeros(n - 1),
        }
        for n in lengths
    ]
    return Dataset.from_trajectories("t", "e", 1, trajs, [0] * len(lengths), success)


def test_performance_is_eq3():
    ds = _lined([2, 4, 4, 10], [True, True, False, False])
    np.testing.assert_allclose(performance(ds, beta=0.1), [1 / 2, 1 / 4, 0.1 / 4, 0.1 / 10])
    # a failure never outranks an equally long success, and shorter successes rank first
    s = performance(ds, 0.1)
    assert s[0] > s[1] > s[2] > s[3]


def test_top_p_keeps_ceil_and_breaks_ties_by_id():
    scores = np.array([0.5, 0.5, 0.5, 0.9, 0.1])
    ids = np.array([40, 10, 30, 20, 0])
    idx = np.arange(5)
    assert top_p(idx, scores, 0.1, ids).tolist() == [3]  # ceil(0.5) = 1: at least one kept
    # three tied at 0.5: ids 10 (pos 1) and 30 (pos 2) win over 40 (pos 0)
    assert top_p(idx, scores, 0.6, ids).tolist() == [1, 2, 3]
    assert top_p(idx, scores, 1.0, ids).tolist() == [0, 1, 2, 3, 4]
    assert n_kept(30, 0.1) == 3 and n_kept(31, 0.1) == 4 and n_kept(1, 0.1) == 1
    assert top_p(np.array([], np.int64), scores, 0.5, ids).size == 0


def test_split_is_seeded_disjoint_and_complete():
    tr, te = split_trajectories(100, 0.2, seed=7)
    assert len(te) == 20 and len(tr) == 80
    assert np.intersect1d(tr, te).size == 0 and np.union1d(tr, te).tolist() == list(range(100))
    tr2, te2 = split_trajectories(100, 0.2, seed=7)
    assert (te == te2).all()
    assert not (te == split_trajectories(100, 0.2, seed=8)[1]).all()
    with pytest.raises(DataError):
        split_trajectories(0, 0.2, 0)


def test_split_holds_out_at_least_one_trajectory():
    # round(0.2 * 2) = 0 would leave the evaluation nothing to test on after all the training
    tr, te = split_trajectories(2, 0.2, seed=0)
    assert len(te) == 1 and len(tr) == 1
    assert [len(split_trajectories(n, 0.2, 0)[1]) for n in (3, 7, 8, 100)] == [1, 1, 2, 20]
    with pytest.raises(DataError, match="ranking.test_fraction"):
        split_trajectories(1, 0.2, 0)


def test_threshold_per_cluster_and_test_subsets_alike(toy):
    cfg = RankConfig()
    tr, te = split_trajectories(toy.n_trajectories, cfg.test_fraction, 0)
    scores = performance(toy, cfg.beta)
    h = threshold(toy.styles, te, scores, toy.trajectory_ids, cfg.ps)
    for (c, p), idx in h.items():
        members = te[toy.styles[te] == c]
        assert len(idx) == n_kept(len(members), p)
        assert set(idx) <= set(members)
        # everything kept scores at least as high as everything dropped
        dropped = np.setdiff1d(members, idx)
        if len(dropped):
            assert scores[idx].min() >= scores[dropped].max()
    # nested: a smaller p keeps a subset of a larger p's trajectories
    assert set(h[(0, 0.1)]) <= set(h[(0, 0.5)]) <= set(h[(0, 1.0)])


def test_rank_config_rejects_bad_values():
    with pytest.raises(ValidationError):
        RankConfig(ps=(1.0, 0.0))
    with pytest.raises(ValidationError):
        RankConfig(ps=(1.5,))
    with pytest.raises(ValidationError):
        RankConfig(beta=0.1, unknown=3)
    with pytest.raises(ValidationError, match="test_fraction"):
        RankConfig(test_fraction=0.0)  # every run evaluates on held-out trajectories


def test_corrupt_labels_exact_fraction_and_always_wrong(rng):
    labels = np.repeat(np.arange(4), 250)
    for c in (0.0, 0.2, 0.6, 1.0):
        bad = corrupt_labels(labels, c, 4, np.random.default_rng(1))
        assert (bad != labels).sum() == round(c * len(labels))
    bad = corrupt_labels(labels, 1.0, 4, rng)
    # wrong labels are uniform over the 3 others: each other label gets ~1/3 of a class
    counts = np.bincount(bad[labels == 0], minlength=4)
    assert counts[0] == 0 and counts[1:].min() > 60
    # "random" mode draws among all k: at c = 1 about 1/k of the labels stay right by chance
    rand = corrupt_labels(labels, 1.0, 4, rng, mode="random")
    assert 0.18 < (rand == labels).mean() < 0.32


def test_plan_cells_builds_pcpg_baseline_and_corruption_cells(toy):
    cfg = RankConfig(ps=(1.0, 0.5))
    tr, _ = split_trajectories(toy.n_trajectories, 0.2, 0)
    cells = plan_cells(toy, toy.styles, tr, cfg, seeds=[0, 1], corruption_levels=(0.0, 0.5))
    keys = [c.key for c in cells]
    assert "k1-p0.5-s1" in keys and "nc-p1-s0" in keys and "corrupt0.5-k0-p1-s1" in keys
    assert len(keys) == len(set(keys)) == 2 * (2 * 2 + 2 + 2 * 2)
    by_key = {c.key: c for c in cells}
    # dedupe keeps the step count: weights sum to the raw steps of the subset
    raw_steps = sum(toy.lengths[i] - 1 for i in tr if toy.styles[i] == 0)
    assert by_key["k0-p1-s0"].weights.sum() == raw_steps
    assert by_key["k0-p1-s0"].n_rows < raw_steps
    # c = 0 corruption is the clean clustering
    assert np.array_equal(by_key["corrupt0-k0-p1-s0"].states, by_key["k0-p1-s0"].states)
    # inputs are normalised on the environment's training rows: one scale for every cell
    assert np.array_equal(by_key["k0-p1-s0"].mean, by_key["nc-p0.5-s1"].mean)


def test_a_group_builds_the_same_cells_as_the_whole_plan(toy):
    """A training task builds only its group's cells (``only``): each equals the whole plan's
    cell of that key, in the plan's order; the specs alone (what the runner cuts into groups)
    come in the same order; a key not in the plan is one clear error."""
    cfg = RankConfig(ps=(1.0, 0.5))
    tr, _ = split_trajectories(toy.n_trajectories, 0.2, 0)
    args = dict(seeds=[0, 1], corruption_levels=(0.0, 0.5))
    whole = plan_cells(toy, toy.styles, tr, cfg, **args)
    specs = [spec for spec, _ in cell_subsets(toy, toy.styles, tr, cfg, **args)]
    assert [s.key for s in specs] == [c.key for c in whole]
    group = [whole[5].key, whole[1].key, whole[-1].key]
    part = plan_cells(toy, toy.styles, tr, cfg, **args, only=group)
    assert [c.key for c in part] == [whole[1].key, whole[5].key, whole[-1].key]
    by_key = {c.key: c for c in whole}
    for cell in part:
        full = by_key[cell.key]
        assert cell.spec == full.spec and cell.n_trajectories == full.n_trajectories
        for name in ("states", "valid", "actions", "weights", "mean", "std"):
            assert np.array_equal(getattr(cell, name), getattr(full, name)), name
    with pytest.raises(DataError, match="no cell k9-p1-s0"):
        plan_cells(toy, toy.styles, tr, cfg, **args, only=["k9-p1-s0"])


def test_plan_cells_skips_a_cluster_without_training_trajectories(toy):
    """k above the number of styles can leave a cluster empty: it gets no agent (the evaluation
    scores its test trajectories with No Clustering's agent), never a crash."""
    tr, _ = split_trajectories(toy.n_trajectories, 0.2, 0)
    labels = np.where(toy.styles == 1, 2, 0)  # no trajectory labelled 1
    cells = plan_cells(
        toy, labels, tr, RankConfig(ps=(1.0, 0.5)), seeds=[0], k=3, corruption_levels=(0.0,)
    )
    keys = {c.key for c in cells}
    assert {"k0-p1-s0", "k2-p0.5-s0", "nc-p1-s0", "corrupt0-k2-p1-s0"} <= keys
    assert not any(k.startswith(("k1-", "corrupt0-k1-")) for k in keys)
    assert all(c.n_trajectories > 0 for c in cells)


def test_custom_score_is_used(toy):
    tr, _ = split_trajectories(toy.n_trajectories, 0.2, 0)
    longest = plan_cells(
        toy,
        toy.styles,
        tr,
        RankConfig(ps=(0.1,)),
        [0],
        baseline=False,
        score=lambda ds: ds.lengths.astype(float),
    )
    shortest = plan_cells(toy, toy.styles, tr, RankConfig(ps=(0.1,)), [0], baseline=False)
    assert longest[0].weights.sum() > shortest[0].weights.sum()
    with pytest.raises(DataError, match="shape"):
        plan_cells(toy, toy.styles, tr, RankConfig(), [0], score=lambda ds: np.ones(3))


def test_a_score_that_is_not_finite_names_the_trajectory(toy):
    """Rewards of 1e308 summed to inf: the message named nothing (no data, trajectory or count)."""
    tr, _ = split_trajectories(toy.n_trajectories, 0.2, 0)
    overflow = np.where(np.arange(toy.n_trajectories) % 3 == 1, np.inf, 1.0)
    with pytest.raises(DataError) as e:
        plan_cells(
            toy, toy.styles, tr, RankConfig(), [0], score=lambda ds: overflow[: ds.n_trajectories]
        )
    n = toy.n_trajectories
    assert (
        f"{toy.domain}-{toy.env}: the skill score of trajectory {toy.trajectory_ids[1]} is inf "
        f"({(n + 1) // 3} of {n} trajectories not finite)"
    ) in str(e.value)


def test_style_margin_ranks_ambiguous_trajectories_last_in_training_and_test_alike(toy):
    """ranking.style_margin: a trajectory whose cluster is barely more likely than the next best
    ranks after every other of its cluster (then by skill, then by id); 0 is the paper's ranking."""
    from pcpg_dist.stages.ranking import ranked_last

    scores = np.array([0.9, 0.8, 0.7, 0.6, 0.5])
    ids = np.arange(5)
    last = np.array([True, False, True, False, False])
    idx = np.arange(5)
    assert top_p(idx, scores, 0.4, ids, last).tolist() == [1, 3]  # not the two best: ranked last
    assert top_p(idx, scores, 0.8, ids, last).tolist() == [0, 1, 3, 4]  # then the better of the two
    assert top_p(idx, scores, 0.4, ids).tolist() == [0, 1]

    n = toy.n_trajectories
    margins = np.linspace(0.0, 5.0, n)
    assert ranked_last(margins, RankConfig(), toy) is None  # the paper's Step B by default
    np.testing.assert_array_equal(
        ranked_last(margins, RankConfig(style_margin=1.0), toy), margins < 1.0
    )
    tr, te = split_trajectories(n, 0.2, 0)
    cfg = RankConfig(ps=(0.25,), style_margin=1.0)
    plain = plan_cells(
        toy,
        toy.styles,
        tr,
        cfg.model_copy(update={"style_margin": 0.0}),
        [0],
        baseline=False,
        margins=margins,
    )
    aware = plan_cells(toy, toy.styles, tr, cfg, [0], baseline=False, margins=margins)
    assert [c.n_trajectories for c in aware] == [c.n_trajectories for c in plain]  # same ceil(p n)
    args = (toy.styles, tr, performance(toy), toy.trajectory_ids, [0.25])
    ambiguous_kept = []
    for c in range(int(toy.styles.max()) + 1):
        kept = threshold(*args, last=margins < 1.0)[(c, 0.25)]
        members = tr[toy.styles[tr] == c]
        assert (margins[members] >= 1.0).sum() >= len(kept)  # enough confident ones...
        assert (margins[kept] >= 1.0).all()  # ...so no ambiguous one is kept
        ambiguous_kept.append((margins[threshold(*args)[(c, 0.25)]] < 1.0).sum())
    assert sum(ambiguous_kept) > 0  # the paper's ranking keeps some
    with pytest.raises(DataError, match="style_margin.*no likelihood margins"):
        plan_cells(toy, toy.styles, tr, cfg, [0])
    with pytest.raises(DataError, match="shape"):
        plan_cells(toy, toy.styles, tr, cfg, [0], margins=np.zeros(3))
