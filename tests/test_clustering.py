"""Step A: the clusterers separate clear styles, handle odd inputs, persist, and are repeatable."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from pydantic import ValidationError

from pcpg_dist.clustering import (
    ClusterConfig,
    cluster,
    cluster_sizes,
    clustering_metrics,
    hungarian_mapping,
    load_model,
)
from pcpg_dist.dataset import Dataset
from pcpg_dist.errors import DataError
from pcpg_dist.parallel import set_threads

# Small and fast: the tests prove behaviour, the benchmark proves the GridWorld targets.
FAST = dict(
    hidden_size=16,
    latent_size=4,
    pretrain_epochs=20,
    dec_epochs=3,
    batch_size=32,
    lr=1e-2,
    kmeans_n_init=4,
)
DRIFTS = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])


def drifting_walks(
    n_per_style: int, seed: int, min_len: int = 8, max_len: int = 25, n_single: int = 0
) -> Dataset:
    """Four styles = four drift directions of a noisy 2-D walk, plus a flag (styles 1 and 3) that
    switches on half-way; lengths vary. ``n_single`` extra length-1 trajectories (style -1) sit
    at the origin."""
    rng = np.random.default_rng(seed)
    trajs, styles = [], []
    for s, drift in enumerate(DRIFTS):
        for _ in range(n_per_style):
            t = int(rng.integers(min_len, max_len + 1))
            steps = drift + 0.3 * rng.standard_normal((t - 1, 2))
            pos = np.vstack([np.zeros(2), np.cumsum(steps, axis=0)])
            flag = (np.arange(t) > t // 2).astype(float) * (s % 2)
            trajs.append(_traj(np.column_stack([pos, flag])))
            styles.append(s)
    for _ in range(n_single):
        trajs.append(_traj(np.zeros((1, 3))))
        styles.append(-1)
    return Dataset.from_trajectories("toy", "walks", 4, trajs, styles, [True] * len(trajs))


def _traj(states: np.ndarray) -> dict[str, np.ndarray]:
    t = len(states)
    return {
        "states": states,
        "actions": np.zeros(t - 1, np.int64),
        "valid": np.full(t, 15),
        "rewards": np.zeros(t - 1),
    }


@pytest.fixture(scope="module")
def walks() -> Dataset:
    set_threads(1)
    return drifting_walks(30, seed=3)


@pytest.fixture(scope="module")
def fitted(walks):
    return cluster(walks, ClusterConfig(**FAST), seed=0)


# ------------------------------------------------------------------------- separation
def test_lstm_dec_separates_clear_styles(walks, fitted):
    m = clustering_metrics(walks.styles, fitted.labels, fitted.latents)
    assert m["ari"] >= 0.9 and m["accuracy"] >= 0.95, m
    assert set(np.unique(fitted.labels)) == {0, 1, 2, 3}
    assert fitted.metrics["silhouette"] > 0.3
    assert fitted.latents.shape == (walks.n_trajectories, FAST["latent_size"])
    # label-free: cluster() reports no supervised score
    assert not {"ari", "nmi", "accuracy"} & set(fitted.metrics)
    assert fitted.sizes.sum() == walks.n_trajectories


@pytest.mark.parametrize("method", ["lstm_kmeans", "summary_kmeans"])
def test_comparison_clusterers_share_the_interface(walks, method):
    res = cluster(walks, ClusterConfig(method=method, **FAST), seed=0)
    assert clustering_metrics(walks.styles, res.labels)["ari"] >= 0.9
    np.testing.assert_array_equal(res.model.predict(walks), res.labels)


def test_variable_lengths_including_length_one():
    ds = drifting_walks(12, seed=5, min_len=1, max_len=30, n_single=5)
    assert ds.lengths.min() == 1
    res = cluster(ds, ClusterConfig(**FAST), seed=0)
    assert (
        res.labels.shape == (ds.n_trajectories,) and res.labels.min() >= 0 and res.labels.max() < 4
    )
    # identical length-1 trajectories get identical latents and one label
    singles = np.nonzero(ds.styles == -1)[0]
    assert len(set(res.labels[singles].tolist())) == 1
    np.testing.assert_allclose(
        res.latents[singles],
        np.broadcast_to(res.latents[singles[0]], (len(singles), FAST["latent_size"])),
        atol=1e-5,
    )
    # predicting a subset made only of length-1 trajectories works too
    np.testing.assert_array_equal(res.model.predict(ds.subset(singles)), res.labels[singles])


# ------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_states_fail_with_data_error(walks, fitted, bad):
    ds = walks.subset(np.arange(walks.n_trajectories))  # a private copy to break
    ds.states[ds.offsets[7] + 1, 0] = bad  # bypasses Dataset validation, as a caller's code can
    with pytest.raises(DataError, match="trajectory 7 .*NaN or infinite"):
        cluster(ds, ClusterConfig(**FAST), seed=0)
    with pytest.raises(DataError, match="NaN or infinite"):
        fitted.model.predict(ds)


def test_empty_subset_and_too_few_trajectories_fail_with_data_error(walks):
    with pytest.raises(DataError, match="no trajectories"):
        cluster(walks.subset([]), ClusterConfig(**FAST), seed=0)
    with pytest.raises(DataError, match="fewer than k=4"):
        cluster(walks.subset([0, 1, 2]), ClusterConfig(**FAST), seed=0)


def test_predict_rejects_other_state_width(fitted):
    other = Dataset.from_trajectories("toy", "wide", 4, [_traj(np.zeros((3, 5)))], [0], [True])
    with pytest.raises(DataError, match="3 state features"):
        fitted.model.predict(other)


def test_config_rejects_bad_values():
    with pytest.raises(ValidationError):
        ClusterConfig(k=0)
    with pytest.raises(ValidationError):
        ClusterConfig(hidden=32)  # unknown key
    with pytest.raises(ValidationError):
        ClusterConfig(method="gmm")


# ------------------------------------------------------------------------- persistence, determinism
def test_save_load_gives_same_assignments(tmp_path, walks, fitted):
    fitted.model.save(tmp_path / "m")
    meta = json.loads((tmp_path / "m" / "cluster_model.json").read_text())
    assert meta["method"] == "lstm_dec" and meta["k"] == 4
    loaded = load_model(tmp_path / "m")
    np.testing.assert_array_equal(loaded.predict(walks), fitted.labels)
    fresh = drifting_walks(10, seed=11)  # unseen trajectories: still their own styles
    assert clustering_metrics(fresh.styles, loaded.predict(fresh))["accuracy"] >= 0.9


def test_load_model_errors_are_data_errors(tmp_path, fitted):
    with pytest.raises(DataError, match="not found"):
        load_model(tmp_path / "nothing")
    fitted.model.save(tmp_path / "m")
    (tmp_path / "m" / "cluster_model.pt").write_bytes(b"not a torch file")
    with pytest.raises(DataError, match="unreadable"):
        load_model(tmp_path / "m")


def test_same_seed_same_labels_styles_unused_global_rng_untouched(walks, fitted):
    # The refit sees shuffled true styles: identical labels prove both determinism and that
    # cluster() never reads them.
    shuffled = walks.with_styles(np.random.default_rng(0).permutation(walks.styles))
    state = torch.get_rng_state()
    again = cluster(shuffled, ClusterConfig(**FAST), seed=0)
    assert torch.equal(state, torch.get_rng_state())
    np.testing.assert_array_equal(again.labels, fitted.labels)
    np.testing.assert_array_equal(again.latents, fitted.latents)


# ------------------------------------------------------------------------- metrics
def test_metrics_are_invariant_to_renaming_clusters():
    true = np.array([0, 0, 1, 1, 2, 2, 3, 3])
    pred = np.array([2, 2, 0, 0, 3, 3, 1, 1])
    assert hungarian_mapping(true, pred) == {2: 0, 0: 1, 3: 2, 1: 3}
    m = clustering_metrics(true, pred)
    assert m == pytest.approx({"ari": 1.0, "nmi": 1.0, "accuracy": 1.0})


def test_hungarian_accuracy_with_extra_clusters_and_errors():
    true = np.array([0, 0, 0, 1, 1, 1])
    pred = np.array([5, 5, 7, 9, 9, 9])  # cluster 7 is left over after one-to-one matching
    assert hungarian_mapping(true, pred) == {5: 0, 9: 1, 7: -1}
    assert clustering_metrics(true, pred)["accuracy"] == pytest.approx(5 / 6)
    np.testing.assert_array_equal(cluster_sizes(np.array([0, 2, 2]), 4), [1, 0, 2, 0])
    with pytest.raises(DataError, match="differ in length"):
        clustering_metrics(true, pred[:3])


# ------------------------------------------------------------------------- bag clusterers
@pytest.fixture(scope="module")
def grid_data():
    """One random style-distinct GridWorld layout, 60 PBTG trajectories per style (seconds)."""
    from pcpg_dist.config.stages import PBTGConfig
    from pcpg_dist.domains.gridworld import random_layouts
    from pcpg_dist.pbtg import assemble_dataset, generate_pair

    layout = random_layouts(1, seed=12)[0]
    cfg = PBTGConfig(trajectories_per_style=200, dataset_per_style=60)
    return assemble_dataset([generate_pair(layout, r, cfg, 0) for r in range(4)])


@pytest.mark.parametrize("method", ["bag_kmeans", "bag_mop", "greedy_mix", "bag_auto"])
def test_bag_clusterers_separate_gridworld_styles(grid_data, method):
    res = cluster(grid_data, ClusterConfig(method=method), seed=0)
    m = clustering_metrics(grid_data.styles, res.labels)
    assert m["accuracy"] >= 0.9, m  # the supervised ceiling on this data is 0.975
    assert res.metrics["distinct_trajectories"] < grid_data.n_trajectories  # duplicates collapsed
    if method == "bag_kmeans":  # nearest cluster mean = the k-means labels
        np.testing.assert_array_equal(res.model.predict(grid_data), res.labels)


def test_bag_auto_is_greedy_mix_from_bag_kmeans_without_labels(grid_data):
    shuffled = grid_data.with_styles(np.random.default_rng(1).permutation(grid_data.styles))
    a = cluster(grid_data, ClusterConfig(method="bag_auto"), seed=0)
    b = cluster(shuffled, ClusterConfig(method="bag_auto"), seed=0)
    np.testing.assert_array_equal(a.labels, b.labels)  # same seed, same labels; styles unread
    named = cluster(grid_data, ClusterConfig(method="greedy_mix"), seed=0)
    np.testing.assert_array_equal(named.labels, a.labels)
    km = cluster(grid_data, ClusterConfig(method="bag_kmeans"), seed=0).labels
    assert a.metrics["greedy_mix_moved"] == pytest.approx(float((a.labels != km).mean()))
    assert 0.0 < a.metrics["greedy_mix_noise"] < 1.0


def test_bag_model_saves_and_predicts_unseen_trajectories(tmp_path, grid_data):
    res = cluster(grid_data, ClusterConfig(method="bag_kmeans"), seed=0)
    res.model.save(tmp_path / "m")
    loaded = load_model(tmp_path / "m")
    np.testing.assert_array_equal(loaded.predict(grid_data), res.labels)
    half = grid_data.subset(np.arange(0, grid_data.n_trajectories, 2))
    np.testing.assert_array_equal(loaded.predict(half), res.labels[::2])


def test_bag_auto_falls_back_to_the_lstm_on_continuous_states(walks):
    res = cluster(walks, ClusterConfig(method="bag_auto", **FAST), seed=0)
    assert res.metrics["auto_fell_back_to_lstm"] == 1.0 and res.model.autoencoder is not None
    assert clustering_metrics(walks.styles, res.labels)["accuracy"] >= 0.95
