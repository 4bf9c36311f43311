"""Step A: the clusterers separate clear styles, handle odd inputs, persist, and are repeatable."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from pydantic import ValidationError

from pcpg_dist.common.devices import set_threads
from pcpg_dist.common.errors import DataError
from pcpg_dist.dataset import Dataset
from pcpg_dist.stages.clustering import (
    ClusterConfig,
    cluster,
    cluster_sizes,
    clustering_metrics,
    hungarian_mapping,
    load_model,
)

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
    return cluster(walks, ClusterConfig(method="lstm_dec", **FAST), seed=0)


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
    with pytest.raises(DataError, match="not a pcpg model file"):
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
    from pcpg_dist.domains.gridworld.layout import random_layouts
    from pcpg_dist.domains.gridworld.pbtg import assemble_dataset, generate_pair
    from pcpg_dist.domains.gridworld.settings import PBTGConfig

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
    # greedy_mix is stable here, so nothing else is fitted (stages/clustering/select)
    assert a.metrics["auto_chose_policy_mix"] == 0.0
    assert a.metrics["stability"] == a.metrics["auto_stability_greedy_mix"] > 0.9
    assert "auto_stability_policy_mix" not in a.metrics  # stable enough: nothing else fitted


def test_bag_model_saves_and_predicts_unseen_trajectories(tmp_path, grid_data):
    res = cluster(grid_data, ClusterConfig(method="bag_kmeans"), seed=0)
    res.model.save(tmp_path / "m")
    loaded = load_model(tmp_path / "m")
    np.testing.assert_array_equal(loaded.predict(grid_data), res.labels)
    half = grid_data.subset(np.arange(0, grid_data.n_trajectories, 2))
    np.testing.assert_array_equal(loaded.predict(half), res.labels[::2])


def test_bag_auto_falls_back_to_policy_mix_on_continuous_states():
    from stages.test_policy_mix import FAST as POLICY_FAST
    from stages.test_policy_mix import goal_seekers

    seekers = goal_seekers(40, seed=7)  # continuous states; only the actions show the style
    fast = {k: v for k, v in POLICY_FAST.items() if k != "method"}
    res = cluster(seekers, ClusterConfig(method="bag_auto", **fast), seed=0)
    assert res.metrics["auto_fell_back"] == 1.0 and res.model.method == "policy_mix"
    assert res.margins is not None  # policy_mix has a likelihood: style margins for Step B
    assert clustering_metrics(seekers.styles, res.labels)["accuracy"] >= 0.95


# ------------------------------------------------------------------------- tampered model files
TAMPER_METHODS = (
    "summary_kmeans",
    "lstm_kmeans",
    "visits_kmeans",
    "bag_kmeans",
    "greedy_mix",
    "policy_mix",
)


@pytest.fixture(scope="module")
def saved_models(tmp_path_factory):
    """One small real model of each saved layout, and a dataset file to classify with them."""
    from pcpg_dist.dataset import write_parquet

    rng = np.random.default_rng(5)
    trajs = []
    for s in range(40):  # integer walks: discrete states, as the visit and bag methods need
        t = int(rng.integers(4, 9))
        moves = DRIFTS[(s % 4 + (rng.random(t - 1) < 0.2)) % 4].astype(int)
        states = np.vstack([np.zeros(2, int), np.cumsum(moves, axis=0)]).astype(float)
        trajs.append({**_traj(states), "actions": (s % 4 + np.zeros(t - 1, np.int64)) % 4})
    ds = Dataset.from_trajectories("toy", "ints", 4, trajs, [s % 4 for s in range(40)], [True] * 40)
    root = tmp_path_factory.mktemp("models")
    small = dict(
        k=2,
        hidden_size=8,
        latent_size=3,
        pretrain_epochs=2,
        dec_epochs=0,
        batch_size=16,
        kmeans_n_init=1,
        em_iterations=1,
        policy_steps=2,
    )
    for method in TAMPER_METHODS:
        cluster(ds, ClusterConfig(method=method, **small), seed=0).model.save(root / method)
    write_parquet(ds, root / "data.parquet")
    return root


def _set(name, fn):
    def edit(t, meta):
        t[name] = fn(t[name])

    return edit


def _meta(**changes):
    return lambda t, meta: meta.update(changes)


def _relabel(method):
    return lambda t, meta: meta.update(method=method, config={**meta["config"], "method": method})


def _garbage(path):
    path.write_bytes(b"\x80\x04garbage" * 50)


# (model, edit of (tensors, meta) or of the .pt path, file named, field named)
TAMPERED = {
    "summary mean short": (
        "summary_kmeans",
        _set("mean", lambda x: x[:2]),
        "pt",
        "mean has shape (2,)",
    ),
    "lstm std short": ("lstm_kmeans", _set("std", lambda x: x[:1]), "pt", "std has shape (1,)"),
    "policy_mix mean short": ("policy_mix", _set("mean", lambda x: x[:1]), "pt", "mean has shape"),
    "summary centroids wide": (
        "summary_kmeans",
        _set("centroids", lambda x: torch.zeros(2, x.shape[1] + 3)),
        "pt",
        "centroids has shape (2, 8)",
    ),
    "lstm centroids wide": (
        "lstm_kmeans",
        _set("centroids", lambda x: torch.zeros(2, 6)),
        "pt",
        "centroids has shape (2, 6)",
    ),
    "summary no centroids": (
        "summary_kmeans",
        _set("centroids", lambda x: x[:0]),
        "json",
        "k 2, but cluster_model.pt holds 0 centroids",
    ),
    "visits centroids 1-D": (
        "visits_kmeans",
        _set("centroids", lambda x: x[0]),
        "pt",
        "centroids has shape",
    ),
    "bag centroids 1-D": (
        "bag_kmeans",
        _set("centroids", lambda x: x[0]),
        "pt",
        "centroids has shape",
    ),
    "visits empty vocabulary": (
        "visits_kmeans",
        lambda t, m: t.update(vocabulary=t["vocabulary"][:0], centroids=t["centroids"][:, :0]),
        "pt",
        "vocabulary has 0 states",
    ),
    "lstm labelled summary": ("lstm_kmeans", _relabel("summary_kmeans"), "pt", "holds tensor 'ae."),
    "visits labelled summary": (
        "visits_kmeans",
        _relabel("summary_kmeans"),
        "pt",
        "holds tensor 'vocabulary'",
    ),
    "summary labelled visits": (
        "summary_kmeans",
        _relabel("visits_kmeans"),
        "pt",
        "no tensor 'vocabulary'",
    ),
    "summary std zero": (
        "summary_kmeans",
        _set("std", torch.zeros_like),
        "pt",
        "std has a value of 0.0",
    ),
    "lstm std NaN": (
        "lstm_kmeans",
        _set("std", lambda x: torch.full_like(x, float("nan"))),
        "pt",
        "std has non-finite values",
    ),
    "bag centroids NaN": (
        "bag_kmeans",
        _set("centroids", lambda x: torch.full_like(x, float("nan"))),
        "pt",
        "centroids has non-finite values",
    ),
    "summary centroids complex": (
        "summary_kmeans",
        _set("centroids", lambda x: x.to(torch.complex64)),
        "pt",
        "centroids has dtype complex64",
    ),
    "visits centroids int": (
        "visits_kmeans",
        _set("centroids", lambda x: x.to(torch.int64)),
        "pt",
        "centroids has dtype int64",
    ),
    "k 99": ("summary_kmeans", _meta(k=99), "json", "k 99, but cluster_model.pt holds 2 centroids"),
    "k true": ("summary_kmeans", _meta(k=True), "json", "k True"),
    "bag_n_actions 0": ("bag_kmeans", _meta(bag_n_actions=0), "json", "bag_n_actions 0"),
    "bag_n_actions -3": ("bag_kmeans", _meta(bag_n_actions=-3), "json", "bag_n_actions -3"),
    "bag_n_actions 1e15": (
        "bag_kmeans",
        _meta(bag_n_actions=10**15),
        "json",
        "bag_n_actions 1000000000000000",
    ),
    "bag_sa_keys negative": (
        "bag_kmeans",
        _set("bag_sa_keys", lambda x: -x - 5),
        "pt",
        "bag_sa_keys holds -",
    ),
    "bag_sa_keys huge": (
        "greedy_mix",
        _set("bag_sa_keys", lambda x: x + 10**12),
        "pt",
        "bag_sa_keys holds 1000",
    ),
    "bag_sa_keys unsorted": (
        "bag_kmeans",
        _set("bag_sa_keys", lambda x: x.flip(0)),
        "pt",
        "strictly increasing",
    ),
    "bag_states NaN": (
        "bag_kmeans",
        _set("bag_states", lambda x: torch.full_like(x, float("nan"))),
        "pt",
        "bag_states has non-finite values",
    ),
    "bag_states float16": (
        "greedy_mix",
        _set("bag_states", lambda x: x.half()),
        "pt",
        "bag_states has dtype float16",
    ),
    "greedy votes negative": (
        "greedy_mix",
        _set("greedy_votes", lambda x: -x - 1),
        "pt",
        "greedy_votes has negative values",
    ),
    "state_dim 4.7": ("summary_kmeans", _meta(state_dim=4.7), "json", "state_dim 4.7"),
    "state_dim '4'": ("summary_kmeans", _meta(state_dim="4"), "json", "state_dim '4'"),
    "policy_mix n_actions 5": ("policy_mix", _meta(n_actions=5), "pt", "pm.heads.weight has shape"),
    "policy_mix centroids": (
        "policy_mix",
        _set("centroids", lambda x: x.flip(0)),
        "pt",
        "k x k identity",
    ),
    "format_version '1'": (
        "summary_kmeans",
        _meta(format_version="1"),
        "json",
        "format_version '1', expected 1",
    ),
    "garbage .pt": (
        "summary_kmeans",
        _garbage,
        "pt",
        "not a pcpg model file (torch could not read its tensors)",
    ),
}


@pytest.mark.parametrize("case", list(TAMPERED))
def test_tampered_cluster_model_is_one_line_naming_file_and_field(
    tmp_path, capsys, saved_models, case
):
    """Tensors of the wrong shape, dtype or range, and JSON that disagrees with them: one line
    naming the file and the field, from load_model and `pcpg classify` alike (were tracebacks, or
    exit 0 with other labels)."""
    import shutil
    import warnings

    from pcpg_dist.cli import main

    method, edit, where, needle = TAMPERED[case]
    d = tmp_path / "m"
    shutil.copytree(saved_models / method, d)
    pt, js = d / "cluster_model.pt", d / "cluster_model.json"
    if edit is _garbage:
        edit(pt)
    else:
        tensors, meta = torch.load(pt, weights_only=True), json.loads(js.read_text())
        edit(tensors, meta)
        torch.save(tensors, pt)
        js.write_text(json.dumps(meta))
    named = pt if where == "pt" else js
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(DataError) as info:
            load_model(d)
    assert str(info.value).startswith(f"{named}: ") and needle in str(info.value)
    assert "\n" not in str(info.value) and len(str(info.value)) < 400 and not caught
    assert "weights_only" not in str(info.value)
    capsys.readouterr()
    code = main(
        [
            "-q",
            "classify",
            str(d),
            str(saved_models / "data.parquet"),
            "--out",
            str(tmp_path / "o.csv"),
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [f"pcpg: error: {info.value}"]
    assert not (tmp_path / "o.csv").exists()


def test_untampered_models_still_load_and_classify(saved_models):
    from pcpg_dist.dataset import read_parquet

    for method in TAMPER_METHODS:
        model = load_model(saved_models / method)
        ds = read_parquet(saved_models / "data.parquet")
        assert model.k == 2 and model.predict(ds).shape == (ds.n_trajectories,)


def test_bag_auto_hands_a_log_whose_actions_say_nothing_to_lstm_dec(walks):
    """The walks log one action throughout: only the states show the style, which a mixture of
    policies cannot see and the sequence model can."""
    res = cluster(walks, ClusterConfig(method="bag_auto", **FAST), seed=0)
    assert res.metrics["auto_fell_back"] == 1.0 and res.metrics["auto_fell_back_to_lstm"] == 1.0
    assert clustering_metrics(walks.styles, res.labels)["accuracy"] >= 0.95
