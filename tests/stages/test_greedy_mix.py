"""greedy_mix (the default clusterer on discrete states): it recovers styles a bad start mixes up,
its ascent never lowers its likelihood, it closes the paper's E4 gap, and its model persists."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pcpg_dist.common.errors import DataError
from pcpg_dist.stages.clustering import (
    ClusterConfig,
    cluster,
    clustering_metrics,
    greedy_likelihood,
    greedy_mix,
    load_model,
)


def synthetic_steps(
    seed: int, k: int = 3, per_style: int = 100, n_states: int = 60, length: int = 25
):
    """k styles = k random greedy actions per state; each trajectory strays uniformly with its own
    noise eps ~ U[0, 0.3]. States are drawn at random (the model never looks at transitions)."""
    rng = np.random.default_rng(seed)
    greedy = rng.integers(0, 4, (k, n_states))
    styles = np.repeat(np.arange(k), per_style)
    n = len(styles)
    state = rng.integers(0, n_states, (n, length))
    eps = rng.uniform(0.0, 0.3, n)
    stray = rng.random((n, length)) < eps[:, None]
    action = np.where(stray, rng.integers(0, 4, (n, length)), greedy[styles[:, None], state])
    traj = np.repeat(np.arange(n), length)
    steps = greedy_mix.Steps.build(
        state.ravel(), action.ravel(), np.ones((n * length, 4), bool), traj, n, n_states, 4
    )
    return steps, styles


def test_recovers_styles_that_a_bad_start_mixes_up():
    steps, styles = synthetic_steps(0)
    rng = np.random.default_rng(1)
    start = np.where(rng.random(len(styles)) < 0.3, rng.integers(0, 3, len(styles)), styles)
    assert clustering_metrics(styles, start)["accuracy"] < 0.85
    fit = greedy_mix.fit(steps, [start], 3)
    assert clustering_metrics(styles, fit.labels)["accuracy"] >= 0.98
    assert fit.moved > 0.1 and 0.05 < fit.noise < 0.3  # the data's mean noise is 0.15
    again = greedy_mix.fit(steps, [start], 3)
    np.testing.assert_array_equal(again.labels, fit.labels)  # no randomness
    ones = np.ones(len(styles))
    assert fit.log_likelihood >= greedy_mix.profile_log_likelihood(steps, ones, start, 3)[0]


@pytest.mark.parametrize("eps", [0.05, 0.3])
def test_ascent_never_lowers_the_likelihood(eps):
    steps, styles = synthetic_steps(2, per_style=40)
    start = np.random.default_rng(3).integers(0, 3, len(styles))
    ones = np.ones(len(styles))
    labels, sweeps = greedy_mix.ascend(steps, ones, start, 3, eps, max_sweeps=100)
    assert sweeps < 100  # converged: a sweep with no move
    before = greedy_likelihood.log_likelihood(steps, ones, start, 3, eps)
    assert greedy_likelihood.log_likelihood(steps, ones, labels, 3, eps) > before
    # a local optimum: no single trajectory can still raise the likelihood by moving
    relabelled, more = greedy_mix.ascend(steps, ones, labels, 3, eps, max_sweeps=100)
    np.testing.assert_array_equal(relabelled, labels)
    assert more == 1


@pytest.fixture(scope="module")
def e4():
    """The paper's E4 at the paper's size (PBTG, 1000 trajectories per style, seed 0)."""
    from pathlib import Path

    from pcpg_dist.domains.gridworld.layout import load_layout
    from pcpg_dist.domains.gridworld.pbtg import assemble_dataset, generate_pair
    from pcpg_dist.domains.gridworld.settings import PBTGConfig

    layout = load_layout(
        Path(__file__).resolve().parents[2] / "pcpg_dist" / "data" / "gridworld" / "E4.txt"
    )
    return assemble_dataset([generate_pair(layout, r, PBTGConfig(), 0) for r in range(4)])


def test_closes_the_paper_e4_gap_to_the_supervised_ceiling(e4):
    """bag_kmeans leaves ~100 R4 trajectories with R3 (both-bonus routes that share R3's way to
    B2); the supervised ceiling is 0.963. The policy model moves them back."""
    from pcpg_dist.stages.clustering.ceiling import supervised_ceiling

    top = supervised_ceiling(e4, seed=0)
    km = clustering_metrics(
        e4.styles, cluster(e4, ClusterConfig(method="bag_kmeans"), seed=0).labels
    )
    auto = cluster(e4, ClusterConfig(), seed=0)  # the default, bag_auto
    acc = clustering_metrics(e4.styles, auto.labels)["accuracy"]
    assert km["accuracy"] < top - 0.015
    assert acc >= top - 0.01, (acc, top)


def test_split_merge_frees_a_group_no_start_freed():
    """Held-out layout R0016 of the issue's family 9172024: the best k-means start converges 1.1
    points below the supervised ceiling, with a group of one style held in another's cluster.
    Starting from the true styles reaches a *higher* likelihood, so the search, not the model, was
    the limit; split-and-merge moves find that labelling without labels."""
    from pcpg_dist.domains.gridworld.layout import random_layouts
    from pcpg_dist.domains.gridworld.pbtg import assemble_dataset, generate_pair
    from pcpg_dist.domains.gridworld.settings import PBTGConfig
    from pcpg_dist.stages.clustering import checked_sequences
    from pcpg_dist.stages.clustering.ceiling import ceiling_panel
    from pcpg_dist.stages.clustering.features import fit_vocabulary

    (layout,) = random_layouts(1, 917_2024, start=16)
    ds = assemble_dataset([generate_pair(layout, r, PBTGConfig(), 0) for r in range(4)])
    # the linear model on visit bags, the ceiling this was measured against; the panel's best
    # (boosting on profiles) is 0.959 here, 1.7 points above the fit (docs/clustering.md)
    top = ceiling_panel(ds, seed=0)["linear_bags"]
    states, _ = checked_sequences(ds)
    steps = greedy_mix.Steps.of_dataset(ds, states, fit_vocabulary(states, ds.actions, 4).states)
    starts = [
        cluster(ds, ClusterConfig(method="bag_kmeans", k=kk), seed=0).labels for kk in (4, 5, 6)
    ]
    without = greedy_mix.fit(steps, starts, 4, split_merge_rounds=0)
    fitted = greedy_mix.fit(steps, starts, 4)
    accuracy = lambda labels: clustering_metrics(ds.styles, labels)["accuracy"]  # noqa: E731
    assert accuracy(without.labels) < top - 0.01
    assert fitted.split_merges >= 1 and fitted.log_likelihood > without.log_likelihood
    assert accuracy(fitted.labels) >= top - 0.01, (accuracy(fitted.labels), top)
    # the result is a fixed point of the ascent: split-and-merge ends where single moves do
    ones = np.ones(ds.n_trajectories)
    again, sweeps = greedy_mix.ascend(steps, ones, fitted.labels, 4, fitted.noise_start, 100)
    np.testing.assert_array_equal(again, fitted.labels)


def test_model_saves_and_labels_unseen_trajectories(tmp_path, e4):
    train = e4.subset(np.arange(0, e4.n_trajectories, 2))
    test = e4.subset(np.arange(1, e4.n_trajectories, 2))
    res = cluster(train, ClusterConfig(method="greedy_mix"), seed=0)
    res.model.save(tmp_path / "m")
    loaded = load_model(tmp_path / "m")
    assert loaded.method == "greedy_mix" and loaded.greedy is not None
    np.testing.assert_array_equal(loaded.predict(train), res.model.predict(train))
    # the fit scores each trajectory without its own votes, predict with them: nearly the same
    assert (loaded.predict(train) == res.labels).mean() >= 0.99
    fit_acc = clustering_metrics(train.styles, res.labels)["accuracy"]
    assert clustering_metrics(test.styles, loaded.predict(test))["accuracy"] >= fit_acc - 0.02


def test_bad_inputs_and_files_fail_with_one_data_error(tmp_path, e4):
    from tests.stages.test_clustering import drifting_walks

    with pytest.raises(DataError, match="greedy_mix: most states .* occur once"):
        cluster(drifting_walks(10, seed=0), ClusterConfig(method="greedy_mix"), seed=0)
    small = e4.subset(np.arange(0, e4.n_trajectories, 8))
    model = cluster(small, ClusterConfig(method="greedy_mix"), seed=0).model
    model.save(tmp_path / "m")
    tensors = torch.load(tmp_path / "m" / "cluster_model.pt", weights_only=True)
    tensors["greedy_votes"] = tensors["greedy_votes"][:, :3]
    torch.save(tensors, tmp_path / "m" / "cluster_model.pt")
    with pytest.raises(DataError, match=r"greedy_votes has shape \(4, 3, 4\)"):
        load_model(tmp_path / "m")
    model.save(tmp_path / "n")
    tensors = torch.load(tmp_path / "n" / "cluster_model.pt", weights_only=True)
    tensors["greedy_noise"] = torch.tensor([1.5], dtype=torch.float64)
    torch.save(tensors, tmp_path / "n" / "cluster_model.pt")
    with pytest.raises(DataError, match="greedy_noise is 1.5; it lies strictly between 0 and 1"):
        load_model(tmp_path / "n")


def test_fewer_distinct_trajectories_than_clusters(tmp_path, e4):
    """Three distinct trajectories, ten copies each, k = 4: every copy of one trajectory gets one
    label, at most three clusters are used, and the saved model gives the labels back."""
    rows = np.concatenate([np.full(10, i) for i in (0, 1500, 3100)])
    ds = e4.subset(rows)
    res = cluster(ds, ClusterConfig(method="greedy_mix", k=4), seed=0)
    assert len(np.unique(res.labels)) <= 3
    for block in res.labels.reshape(3, 10):
        assert len(set(block)) == 1
    res.model.save(tmp_path / "m")
    np.testing.assert_array_equal(load_model(tmp_path / "m").predict(ds), res.labels)


def test_margins_are_large_for_clear_styles_and_small_for_trajectories_that_fit_two():
    """The clustering's margins (nats from a trajectory's cluster to the next best; what
    ranking.style_margin reads): the fit's labels are their argmax, trajectories that follow one
    style's greedy actions are far from every other cluster, and a trajectory that only visits
    states where two styles act alike is near both."""
    from pcpg_dist.stages.clustering.metrics import likelihood_margins as _margins

    steps, styles = synthetic_steps(4, per_style=80)
    fit = greedy_mix.fit(steps, [styles], 3)
    sc = greedy_mix.fit_scores(steps, fit)
    assert (sc.argmax(1) == fit.labels).mean() >= 0.99
    m = _margins(sc, fit.labels)
    assert np.median(m) > 10.0
    # one more trajectory: 6 steps in states where styles 0 and 1 share the greedy action
    v = fit.votes.argmax(2)  # (k, S) each cluster's greedy action
    c0, c1 = (np.argmax(np.bincount(fit.labels[styles == s], minlength=3)) for s in (0, 1))
    shared = np.flatnonzero(v[c0] == v[c1])[:6]
    assert len(shared) >= 3
    one = greedy_mix.Steps.build(
        shared,
        v[c0][shared],
        np.ones((len(shared), 4), bool),
        np.zeros(len(shared), np.int64),
        1,
        steps.n_states,
        4,
    )
    both = greedy_mix.scores(
        one, greedy_likelihood.vote_weights(one, fit.noise), fit.votes, fit.log_share
    )[0]
    assert abs(both[c0] - both[c1]) < 1.0 < min(both[c0], both[c1]) - both.min()
