"""The supervised ceiling's features: the vocabulary cap keeps whole counts, so no order decides."""

import numpy as np

from pcpg_dist.stages.clustering import ceiling


def test_the_cap_keeps_or_drops_a_count_whole(monkeypatch):
    """Ids tied at the boundary count are all left out (here ids seen twice, with most of the cap
    kept): which of equally frequent ids would have been kept must not depend on the ids' order
    (on MiniDungeons it moved the ceiling 0.7 points)."""
    monkeypatch.setattr(ceiling, "MAX_VOCAB", 3)
    ids = np.array([7] * 5 + [3] * 4 + [9, 9] + [1, 1] + [4, 4] + [8])  # counts 5, 4, 2, 2, 2, 1
    traj = np.arange(len(ids)) % 4
    bag = ceiling._bag(ids, traj, 4)
    assert bag.shape == (4, 2)  # the ids of counts 5 and 4; the three of count 2 tie at the cap
    relabelled = ceiling._bag(
        np.array([{7: 2, 3: 6, 9: 0, 1: 5, 4: 3, 8: 1}[int(i)] for i in ids]), traj, 4
    )
    assert sorted(map(tuple, bag.T.toarray())) == sorted(map(tuple, relabelled.T.toarray()))


def test_ids_tied_at_a_shared_count_fill_the_cap_rather_than_empty_it(monkeypatch):
    """Leaving out every id tied at the boundary count could keep almost nothing (30 ids seen twice
    and one seen three times: 1 feature of a cap of 20). Ids seen once carry nothing across
    trajectories and are still left out; ids tied at a larger count fill the cap in id order."""
    monkeypatch.setattr(ceiling, "MAX_VOCAB", 20)
    ids = np.array([0, 0, 0] + [i for i in range(1, 31) for _ in range(2)])
    bag = ceiling._bag(ids, np.arange(len(ids)) % 7, 7)
    assert bag.shape == (7, 20)
    once = np.array(
        [0, 0, 0] + list(range(1, 31))
    )  # 30 ids seen once: only the id seen thrice is kept
    assert ceiling._bag(once, np.arange(len(once)) % 7, 7).shape == (7, 1)


def test_under_the_cap_every_id_is_a_feature():
    ids = np.array([0, 0, 1, 2, 2, 2])
    bag = ceiling._bag(ids, np.array([0, 1, 1, 0, 1, 1]), 2)
    assert bag.toarray().tolist() == [[1, 1, 0], [1, 1, 1]]  # columns by count: ids 2, 0, 1
    assert set(bag.data) == {1.0}  # visited or not, not how often


def test_a_gap_of_float_noise_is_zero_not_minus_zero():
    """MiniDungeons' seed-0 clustering equals its ceiling (677 of 780): the two fractions differ by
    1e-16 in floating point, which tables printed as "-0.000", i.e. above the ceiling."""
    top, acc = 0.8679487179487179, 677 / 780
    assert top - acc < 0
    gap = ceiling.gap_to_ceiling(top, acc)
    assert gap == 0.0 and f"{gap:+.3f}" == "+0.000"
    assert ceiling.gap_to_ceiling(0.9, 0.8) == 0.1 and ceiling.gap_to_ceiling(0.8, 0.9) == -0.1


def test_the_ceiling_is_scored_unless_the_config_turns_it_off():
    """`clustering.ceiling: false` leaves out the panel and the gap, and only them: the clustering
    and its scores against the styles are the same."""
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.domains.base import Unit
    from pcpg_dist.pipeline import cluster_unit
    from tests.stages.test_policy_mix import goal_seekers

    ds = goal_seekers(20, seed=7)
    unit = Unit("goals", ds, np.arange(0))
    on = cluster_unit(unit, ClusterConfig(k=2, confidence_runs=0), 0)
    off = cluster_unit(unit, ClusterConfig(k=2, confidence_runs=0, ceiling=False), 0)
    assert on.metrics["clustering/ceiling"] > 0.9  # the goal seekers' styles are separable
    assert on.metrics["clustering/gap_to_ceiling"] == ceiling.gap_to_ceiling(
        on.metrics["clustering/ceiling"], on.metrics["clustering/accuracy"]
    )
    assert not any("ceiling" in k for k in off.metrics)
    assert np.array_equal(on.labels, off.labels)
    same = {k: v for k, v in on.metrics.items() if "ceiling" not in k and "seconds" not in k}
    assert same == {k: v for k, v in off.metrics.items() if "seconds" not in k}
