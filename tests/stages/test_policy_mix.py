"""policy_mix: a mixture of k neural policies over whole trajectories (continuous states)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from sklearn.cluster import KMeans

from pcpg_dist.common.devices import set_threads
from pcpg_dist.common.errors import DataError
from pcpg_dist.dataset import Dataset
from pcpg_dist.stages.clustering import (
    ClusterConfig,
    cluster,
    clustering_metrics,
    counter_summary,
    load_model,
    monotone_features,
)
from pcpg_dist.stages.clustering.policy_mix import fit_sample
from pcpg_dist.stages.clustering.policy_network import PolicyMixture, picked_log_probs, tanh

MOVES = np.array([[-1, 0], [0, 1], [1, 0], [0, -1]], float)  # up, right, down, left
FAST = dict(method="policy_mix", k=4, hidden_size=16, kmeans_n_init=4)


def goal_seekers(n_per_style: int, seed: int, lengths: tuple[int, int] = (10, 30)) -> Dataset:
    """Four styles, each heading for its own one of four goals. Every state holds the unit
    direction to each goal (8 numbers, fresh each step, as if the map changed) and a step
    counter; the actions are the moves toward the style's goal, with 20 % random moves. Lengths
    are drawn independently of style, so the counter says nothing: only the actions do."""
    rng = np.random.default_rng(seed)
    trajs, styles = [], []
    for style in range(4):
        for _ in range(n_per_style):
            t = int(rng.integers(*lengths))
            move = rng.integers(0, 4, size=(t, 4))  # the best move toward each goal, per step
            states = np.column_stack([MOVES[move].reshape(t, 8), np.arange(t) / 100])
            greedy = move[:-1, style]
            actions = np.where(rng.random(t - 1) < 0.2, rng.integers(0, 4, t - 1), greedy)
            trajs.append(
                {
                    "states": states,
                    "actions": actions,
                    "valid": np.full(t, 15),
                    "rewards": np.zeros(t - 1),
                }
            )
            styles.append(style)
    return Dataset.from_trajectories("toy", "goals", 4, trajs, styles, [True] * len(trajs))


@pytest.fixture(scope="module")
def goals() -> Dataset:
    set_threads(1)
    return goal_seekers(40, seed=7)


@pytest.fixture(scope="module")
def fitted(goals):
    return cluster(goals, ClusterConfig(**FAST), seed=0)


def test_separates_styles_that_only_the_actions_show(goals, fitted):
    # k-means on the counter is near chance here: only the actions show the styles
    summary = counter_summary(goals.states, goals.offsets)
    start = KMeans(4, n_init=4, random_state=0).fit_predict(summary)
    assert clustering_metrics(goals.styles, start)["accuracy"] < 0.45
    m = clustering_metrics(goals.styles, fitted.labels)
    assert m["accuracy"] >= 0.95, m
    by_counters = cluster(goals, ClusterConfig(**FAST, policy_start="counters"), seed=0)
    assert clustering_metrics(goals.styles, by_counters.labels)["accuracy"] >= 0.95
    assert by_counters.metrics["em_rounds"] >= 2  # from counters EM has to find the styles
    assert fitted.latents.shape == (goals.n_trajectories, 4)  # posteriors over the k policies
    np.testing.assert_allclose(fitted.latents.sum(axis=1), 1.0, atol=1e-5)
    assert not {"ari", "nmi", "accuracy"} & set(fitted.metrics)


def test_no_silhouette_is_reported_its_posteriors_read_separated_even_without_styles(goals):
    # one style only: no play-styles to find, yet EM's posteriors over whole trajectories are
    # near one-hot, so their silhouette would tell a user the clusters are well separated
    from sklearn.metrics import silhouette_score

    one_style = goals.subset(np.flatnonzero(np.asarray(goals.styles) == 0))
    found = cluster(one_style, ClusterConfig(**FAST), seed=0)
    assert silhouette_score(found.latents, found.labels) > 0.8
    assert "silhouette" not in found.metrics and found.metrics["size_min_frac"] > 0
    kmeans = cluster(goals, ClusterConfig(method="summary_kmeans", k=4), seed=0)
    assert -1 <= kmeans.metrics["silhouette"] <= 1  # clusterers of a feature space still say it


def test_same_seed_same_labels_and_global_rng_untouched(goals, fitted):
    torch.manual_seed(123)
    before = torch.rand(1)
    torch.manual_seed(123)
    again = cluster(goals, ClusterConfig(**FAST), seed=0)
    assert torch.equal(torch.rand(1), before)
    np.testing.assert_array_equal(again.labels, fitted.labels)
    shuffled = goals.with_styles(np.zeros(goals.n_trajectories, np.int64))
    np.testing.assert_array_equal(
        cluster(shuffled, ClusterConfig(**FAST), seed=0).labels, fitted.labels
    )  # never reads the styles


def test_saved_model_predicts_the_same_and_unseen_trajectories(tmp_path, goals, fitted):
    fitted.model.save(tmp_path / "m")
    model = load_model(tmp_path / "m")
    np.testing.assert_array_equal(model.predict(goals), fitted.labels)
    fresh = goal_seekers(10, seed=99)
    m = clustering_metrics(fresh.styles, model.predict(fresh))
    assert m["accuracy"] >= 0.9, m


def test_bad_input_and_bad_files_are_data_errors(tmp_path, goals, fitted):
    no_actions = Dataset.from_trajectories(
        "toy",
        "still",
        4,
        [
            {
                "states": np.zeros((1, 9)),
                "actions": np.zeros(0, np.int64),
                "valid": np.full(1, 15),
                "rewards": np.zeros(0),
            }
        ]
        * 4,
        [0] * 4,
        [True] * 4,
    )
    with pytest.raises(DataError, match="no step with an action"):
        cluster(no_actions, ClusterConfig(**FAST), seed=0)
    fitted.model.save(tmp_path / "m")
    meta = json.loads((tmp_path / "m" / "cluster_model.json").read_text())
    meta["n_actions"] = "four"
    (tmp_path / "m" / "cluster_model.json").write_text(json.dumps(meta))
    with pytest.raises(DataError, match="n_actions"):
        load_model(tmp_path / "m")
    meta["n_actions"] = 5
    (tmp_path / "m" / "cluster_model.json").write_text(json.dumps(meta))
    with pytest.raises(
        DataError,
        match=r"pm.heads.weight has shape \(16, 16\); .*needs \(20, 16\) \(from .*n_actions in cluster_model.json\)",
    ):
        load_model(tmp_path / "m")


def test_counters_are_found_without_labels():
    # feature 0 counts up, 1 goes up and down, 2 is constant, 3 restarts at 0 in each trajectory
    a = np.array([[0, 1, 5, 0], [1, 0, 5, 1], [2, 1, 5, 2]], float)
    b = np.array([[0, 0, 5, 0], [0, 1, 5, 3]], float)
    states, offsets = np.vstack([a, b]), np.array([0, 3, 5])
    np.testing.assert_array_equal(monotone_features(states, offsets), [0, 3])
    summary = counter_summary(states, offsets)  # gain and mean of features 0 and 3
    assert summary.shape == (2, 4)
    np.testing.assert_allclose(summary.mean(axis=0), 0, atol=1e-9)


def test_an_emptied_cluster_takes_the_worst_explained_half_of_the_largest():
    from pcpg_dist.stages.clustering.policy_mix import reseed_small

    labels = np.array([0, 0, 0, 0, 0, 0, 1, 1, 1, 2])  # cluster 2 holds 1 of 10, k = 3
    steps = np.array([10, 10, 20, 20, 10, 10, 5, 5, 5, 5], float)
    scores = np.zeros((3, 10))
    scores[0, :6] = [-1, -9, -2, -40, -3, -4]  # per step: -0.1 -0.9 -0.1 -2.0 -0.3 -0.4
    out = labels.copy()
    assert reseed_small(out, scores, steps, 3, 0.25) == 0  # 1 >= 0.25 * 10 / 3: kept
    assert reseed_small(out, scores, steps, 3, 0.5) == 1  # 1 < 0.5 * 10 / 3: re-seeded
    np.testing.assert_array_equal(out, [0, 2, 0, 2, 0, 2, 1, 1, 1, 2])
    assert reseed_small(labels.copy(), scores, steps, 3, 0.0) == 0


def test_em_started_from_given_labels_keeps_their_names(goals):
    # benchmarks/zoo/search.py starts EM from the true styles to tell the search from the objective
    from pcpg_dist.config.clustering import ClusterConfig as Cfg
    from pcpg_dist.stages.clustering.policy_mix import _fit_policy_mix

    start = (np.asarray(goals.styles) + 1) % 4  # the styles under other names
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        labels, *_ = _fit_policy_mix(
            goals, goals.states, goals.offsets, Cfg(**FAST), 0, {}, start, first_round_steps=200
        )
    assert np.mean(labels == start) >= 0.95


def test_a_partitions_fair_score_prefers_the_styles_to_a_shuffle_of_them(goals):
    # benchmarks/zoo/objective.py reads from these scores whose limit a gap is (search, objective)
    from benchmarks.zoo.search import partition_scores

    styles = np.asarray(goals.styles)
    shuffled = np.random.default_rng(0).permutation(styles)
    for rows in (0, 500):  # every step, or a sample of 500 of them a fit
        mine = partition_scores(goals, styles, 4, 150, rows=rows)
        other = partition_scores(goals, shuffled, 4, 150, rows=rows)
        assert mine["fit"] > other["fit"] + 0.1, (rows, mine, other)
        assert mine["held_out"] > other["held_out"] + 0.1, (rows, mine, other)
    again = partition_scores(goals, styles, 4, 20, seed=3, rows=500)
    assert again == partition_scores(goals, styles, 4, 20, seed=3, rows=500)


def test_the_ceiling_panel_holds_the_supervised_policy_mixture(goals):
    # given the styles, k policies classify what only the actions show; seeded, the global RNG kept
    from pcpg_dist.stages.clustering.ceiling import ceiling_panel

    torch.manual_seed(5)
    state = torch.random.get_rng_state()
    panel = ceiling_panel(goals, seed=0)
    assert torch.equal(torch.random.get_rng_state(), state)
    assert panel["policy_likelihood"] >= 0.95, panel
    assert ceiling_panel(goals, seed=0) == panel


def schedulers(n_per_style: int, seed: int) -> Dataset:
    """Two styles that take the same actions as often, in another order: one action for the first
    half of the episode, the other for the second (20 % random moves). The states are fresh noise,
    so no policy of the state alone tells them apart; the step's index does."""
    rng = np.random.default_rng(seed)
    trajs, styles = [], []
    for style in range(2):
        for _ in range(n_per_style):
            t = int(rng.integers(20, 25))
            first = np.arange(t - 1) < (t - 1) // 2
            greedy = np.where(first, style, 1 - style)
            actions = np.where(rng.random(t - 1) < 0.2, rng.integers(0, 2, t - 1), greedy)
            trajs.append(
                {
                    "states": rng.normal(size=(t, 3)),
                    "actions": actions,
                    "valid": np.full(t, 3),
                    "rewards": np.zeros(t - 1),
                }
            )
            styles.append(style)
    return Dataset.from_trajectories("toy", "sched", 2, trajs, styles, [True] * len(trajs))


def test_policy_time_tells_apart_styles_that_act_by_schedule(tmp_path):
    from pcpg_dist.stages.clustering.policy_network import policy_inputs, policy_states

    set_threads(1)
    ds = schedulers(30, seed=3)
    cfg = dict(method="policy_mix", k=2, hidden_size=16, kmeans_n_init=4)
    markov = cluster(ds, ClusterConfig(**cfg), seed=0)
    timed = cluster(ds, ClusterConfig(**cfg, policy_time=True), seed=0)
    assert clustering_metrics(ds.styles, markov.labels)["accuracy"] < 0.8
    assert clustering_metrics(ds.styles, timed.labels)["accuracy"] >= 0.95
    # the time column: log(1 + t), t restarting at 0 in each trajectory, then normalised
    seen = policy_states(ds, ds.states, time=True)
    s, a, _, _ = policy_inputs(ds, seen, np.zeros(4), np.full(4, 2.0))
    assert s.shape == (len(a), 4)
    t = np.concatenate([np.arange(n - 1) for n in np.diff(ds.offsets)])
    np.testing.assert_allclose(s[:, 3].numpy(), np.log1p(t) / 2, rtol=1e-6)
    # saved and read back, it keeps seeing the time; a tampered flag is one clear error
    timed.model.save(tmp_path / "m")
    np.testing.assert_array_equal(load_model(tmp_path / "m").predict(ds), timed.labels)
    meta = json.loads((tmp_path / "m" / "cluster_model.json").read_text())
    assert meta["policy_time"] is True
    meta["policy_time"] = "yes"
    (tmp_path / "m" / "cluster_model.json").write_text(json.dumps(meta))
    with pytest.raises(DataError, match="policy_time 'yes'; expected true or false"):
        load_model(tmp_path / "m")


def test_bag_auto_keeps_the_time_step_only_where_its_fit_is_clearly_more_stable(goals):
    # stages/clustering/select: policy_mix with the time step replaces the one without only
    # where its clusters come back on subsamples more often, by more than MARGIN
    from pcpg_dist.stages.clustering.confidence import verdict_of
    from pcpg_dist.stages.clustering.select import MARGIN

    set_threads(1)
    ds = schedulers(30, seed=3)
    chosen = cluster(ds, ClusterConfig(k=2, hidden_size=16, kmeans_n_init=4), seed=0)
    m = chosen.metrics
    assert m["auto_fell_back"] == 1.0 and m["auto_chose_policy_time"] == 1.0
    assert m["auto_stability_policy_mix_time"] > m["auto_stability_policy_mix"] + MARGIN
    assert m["stability"] == m["auto_stability_policy_mix_time"]  # its confidence
    assert clustering_metrics(ds.styles, chosen.labels)["accuracy"] >= 0.95
    assert chosen.model.policy.time
    assert "bag_auto chose policy_mix with the time step" in verdict_of(m, 2).line()
    # where the styles are Markov, whichever is kept still finds them
    plain = cluster(goals, ClusterConfig(k=4, hidden_size=16, kmeans_n_init=4), seed=0)
    assert clustering_metrics(goals.styles, plain.labels)["accuracy"] >= 0.95
    assert plain.model.policy.time == bool(plain.metrics["auto_chose_policy_time"])


def test_a_fit_that_leaves_clusters_empty_never_wins_the_choice_by_its_stability():
    # two refits that put every trajectory in one cluster agree perfectly (ARI 1): such a fit
    # must not stop bag_auto's search nor beat a fit that fills all k clusters
    from pcpg_dist.stages.clustering.select import MARGIN, better, filled
    from pcpg_dist.stages.clustering.step import Clustering

    def fit(used: int) -> Clustering:
        return Clustering(np.zeros(8, np.int64), None, {"n_clusters_used": float(used)}, None, 0.0)

    collapsed, full = fit(1), fit(4)
    assert not filled(collapsed, 4) and filled(full, 4)
    assert better(full, 0.05, collapsed, 1.0, 4)  # fills k: replaces a stabler collapse
    assert not better(collapsed, 1.0, full, 0.05, 4)
    assert better(full, 0.5 + MARGIN + 0.01, fit(4), 0.5, 4)
    assert not better(full, 0.5 + MARGIN, fit(4), 0.5, 4)  # not by more than MARGIN
    assert better(fit(2), 0.9, fit(1), 0.5, 4)  # neither fills k: stability decides


def test_the_time_step_fit_gives_way_to_the_plain_one_where_it_is_not_confident():
    # select.stand_in: policy_mix with the time step, kept for a stability that still reads below
    # "styles found", is a winner's curse; policy_mix without it, if it fills k, is used instead
    from pcpg_dist.stages.clustering.confidence import FOUND, verdict_of
    from pcpg_dist.stages.clustering.select import TIMED, stand_in
    from pcpg_dist.stages.clustering.step import Clustering

    def fit(used: int, stable: float) -> tuple:
        labels = np.zeros(8, np.int64)
        return (
            Clustering(labels, None, {"n_clusters_used": float(used)}, None, 0.0),
            {"stability": stable},
            0,
        )

    low, high = FOUND - 0.1, FOUND + 0.05
    assert stand_in(TIMED, {"policy_mix": fit(4, 0.4), TIMED: fit(4, low)}, 4) == "policy_mix"
    assert stand_in(TIMED, {"policy_mix": fit(4, 0.4), TIMED: fit(4, high)}, 4) == TIMED
    assert stand_in(TIMED, {"policy_mix": fit(3, 0.4), TIMED: fit(4, low)}, 4) == TIMED  # empty
    assert stand_in("greedy_mix", {"greedy_mix": fit(4, 0.6), TIMED: fit(4, 0.3)}, 4) == (
        "greedy_mix"
    )
    said = verdict_of(
        {
            "stability": 0.40,
            "auto_time_set_aside": 1.0,
            "auto_stability_policy_mix": 0.40,
            "auto_stability_policy_mix_time": low,
        },
        4,
    )
    assert "kept policy_mix without the time step (stability 0.40)" in said.line()


def test_policies_fitted_to_a_sample_of_the_steps_still_separate_the_styles():
    gen = torch.Generator().manual_seed(0)
    assert fit_sample(100, 2, 0, gen).tolist() == list(range(100))  # 0: every step
    assert len(fit_sample(100, 1, 32, gen)) == 64  # at least 64 steps a trajectory
    sample = fit_sample(10_000, 10, 3000, gen)
    assert len(sample) == 3000 and len(set(sample.tolist())) == 3000
    assert sample.tolist() == sorted(sample.tolist())
    long = goal_seekers(10, seed=3, lengths=(150, 250))  # 40 trajectories, ~8000 steps
    steps = int((long.actions >= 0).sum())
    sampled = ClusterConfig(**FAST, policy_rows=3000)
    found = cluster(long, sampled, seed=0)
    assert clustering_metrics(long.styles, found.labels)["accuracy"] >= 0.95
    assert found.metrics["policy_fit_steps"] == 3000 < steps  # the policies saw the sample only
    np.testing.assert_array_equal(cluster(long, sampled, seed=0).labels, found.labels)
    whole = cluster(long, ClusterConfig(**FAST, policy_rows=0), seed=0)
    same = cluster(long, ClusterConfig(**FAST, policy_rows=steps), seed=0)
    np.testing.assert_array_equal(same.labels, whole.labels)  # a sample of every step is all


def tasked_goal_seekers(n_per_style: int, seed: int, noise: float) -> Dataset:
    """:func:`goal_seekers` where every episode also has a task (one of four, shown one-hot)
    that sets how fast its counter runs, so k-means on counters sees the tasks, not the styles;
    each style still heads for its own goal, with ``noise`` random moves."""
    rng = np.random.default_rng(seed)
    trajs, styles = [], []
    for style in range(4):
        for _ in range(n_per_style):
            task, t = int(rng.integers(4)), int(rng.integers(10, 30))
            move = rng.integers(0, 4, size=(t, 4))
            shown = np.zeros((t, 4))
            shown[:, task] = 1.0
            counter = np.arange(t) * (task + 1) / 10
            states = np.column_stack([MOVES[move].reshape(t, 8), shown, counter])
            greedy = move[:-1, style]
            actions = np.where(rng.random(t - 1) < noise, rng.integers(0, 4, t - 1), greedy)
            trajs.append(
                {"states": states, "actions": actions, "valid": np.full(t, 15),
                 "rewards": np.zeros(t - 1)}
            )  # fmt: skip
            styles.append(style)
    return Dataset.from_trajectories("toy", "tasked", 4, trajs, styles, [True] * len(trajs))


def test_the_latent_start_finds_styles_where_counters_see_only_the_task(goals):
    from pcpg_dist.stages.clustering.latent_start import latent_start
    from pcpg_dist.stages.clustering.policy_mix import _policy_view

    set_threads(1)
    cfg = ClusterConfig(**FAST)
    assert cfg.policy_start == "latent"  # the default
    inputs = _policy_view(goals, goals.states, cfg)[3]
    alone = latent_start(inputs, goals.n_trajectories, cfg, goals.n_actions, seed=0)
    assert clustering_metrics(goals.styles, alone)["accuracy"] >= 0.9  # before any EM
    again = latent_start(inputs, goals.n_trajectories, cfg, goals.n_actions, seed=0)
    np.testing.assert_array_equal(again, alone)
    ds = tasked_goal_seekers(40, seed=7, noise=0.5)
    by_counters = ClusterConfig(**FAST, policy_start="counters")
    start = KMeans(4, n_init=4, random_state=0).fit_predict(counter_summary(ds.states, ds.offsets))
    assert clustering_metrics(ds.styles, start)["accuracy"] < 0.45  # the tasks, not the styles
    old = clustering_metrics(ds.styles, cluster(ds, by_counters, seed=0).labels)["accuracy"]
    new = clustering_metrics(ds.styles, cluster(ds, cfg, seed=0).labels)["accuracy"]
    assert new >= 0.75 and new >= old + 0.1, (new, old)


@pytest.mark.parametrize("heads", [None, 3])
def test_picked_log_probs_is_the_masked_log_softmax_of_the_taken_action(heads):
    """Values and gradients equal log_softmax over the valid actions, then the taken one's; the
    masked actions get no probability and no gradient."""
    gen = torch.Generator().manual_seed(0)
    rows, n_actions = 50, 5
    shape = (rows, n_actions) if heads is None else (rows, heads, n_actions)
    logits = (3 * torch.randn(shape, generator=gen)).requires_grad_()
    actions = torch.randint(n_actions, (rows,), generator=gen)
    valid = torch.rand(rows, n_actions, generator=gen) > 0.4
    valid[torch.arange(rows), actions] = True
    mask = valid if heads is None else valid[:, None, :]
    index = actions[:, None] if heads is None else actions[:, None, None].expand(rows, heads, 1)
    ref = torch.log_softmax(logits.masked_fill(~mask, -1e9), -1).gather(-1, index).squeeze(-1)
    (ref_grad,) = torch.autograd.grad(ref.sum(), logits)
    got = picked_log_probs(logits, actions, valid)
    (grad,) = torch.autograd.grad(got.sum(), logits)
    assert got.shape == ref.shape
    torch.testing.assert_close(got, ref, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(grad, ref_grad, atol=1e-5, rtol=1e-5)
    assert (grad.masked_select(~mask.expand(shape)) == 0).all()
    assert (got <= 0).all() and (got > -30).all()
    every = torch.ones_like(valid)  # no action masked (the mask is skipped): plain log_softmax
    plain = torch.log_softmax(logits, -1).gather(-1, index).squeeze(-1)
    torch.testing.assert_close(picked_log_probs(logits, actions, every), plain, atol=1e-5, rtol=0)


def test_picked_log_probs_under_a_mask_equals_exp_of_every_entry_and_keeps_far_moves():
    """Few legal ids of many (exp of the masked ones skipped, masked_exp): the same numbers and
    gradients, bit for bit, as exp of every entry; a taken move 120 below the row's best keeps
    its log-probability of about -120 (the floor cuts terms of the sum, never the picked one)."""
    gen = torch.Generator().manual_seed(1)
    rows, heads, n_actions = 400, 4, 65
    logits = (3 * torch.randn(rows, heads, n_actions, generator=gen)).requires_grad_()
    actions = torch.randint(n_actions, (rows,), generator=gen)
    valid = torch.rand(rows, n_actions, generator=gen) < 0.15
    valid[torch.arange(rows), actions] = True
    shifted = logits + torch.zeros(rows, n_actions).masked_fill_(~valid, -1e9)[:, None, :]
    top = shifted.detach().amax(-1, keepdim=True)
    index = actions[:, None, None].expand(rows, heads, 1)
    every = shifted.gather(-1, index) - top - (shifted - top).exp().sum(-1, keepdim=True).log()
    (every_grad,) = torch.autograd.grad(every.sum(), logits)
    got = picked_log_probs(logits, actions, valid)
    (grad,) = torch.autograd.grad(got.sum(), logits)
    assert torch.equal(got, every.squeeze(-1)) and torch.equal(grad, every_grad)
    far = torch.zeros(1, 3)
    far[0, 0] = -120.0
    far_valid = torch.tensor([[True, True, False]])
    assert picked_log_probs(far, torch.tensor([0]), far_valid).item() == pytest.approx(-120.0)


def test_the_clusterers_tanh_is_torchs_in_value_and_gradient():
    """2 sigmoid(2x) - 1 with tanh's own backward: within float32 rounding of torch.tanh over
    the whole range (saturated ends included, never NaN), and the policy trunk has no parameter
    of its own, so saved models keep their keys."""
    x = torch.cat([torch.linspace(-60, 60, 20001), torch.tensor([0.0, 1e-30, -1e-30])])
    x = x.requires_grad_()
    got, ref = tanh(x), torch.tanh(x)
    torch.testing.assert_close(got, ref, atol=3e-7, rtol=0)
    weights = torch.linspace(-1, 1, len(x))
    (grad,) = torch.autograd.grad((got * weights).sum(), x)
    (ref_grad,) = torch.autograd.grad((ref * weights).sum(), x)
    torch.testing.assert_close(grad, ref_grad, atol=1e-6, rtol=0)
    assert torch.isfinite(grad).all() and got.abs().max() <= 1.0
    keys = set(PolicyMixture(3, 8, 2, 4).state_dict())
    assert keys == {
        "trunk.0.weight", "trunk.0.bias", "trunk.2.weight", "trunk.2.bias",
        "heads.weight", "heads.bias", "log_prior",
    }  # fmt: skip


def test_restarts_keep_the_most_stable_of_their_fits():
    # clustering.restarts: each restart is the fit and refits of its own seed; the kept one is
    # the most stable, its labels and stability are that restart's, and the run is repeatable
    from pcpg_dist.stages.clustering.confidence import stability
    from pcpg_dist.stages.clustering.select import RESTART_SEEDS
    from pcpg_dist.stages.clustering.step import cluster_once

    set_threads(1)
    ds = tasked_goal_seekers(8, seed=1, noise=0.6)  # noisy: the restarts' stabilities differ
    cfg = ClusterConfig(**FAST, restarts=3, confidence_runs=1)
    kept = cluster(ds, cfg, seed=0)
    fits = [cluster_once(ds, cfg, RESTART_SEEDS * r) for r in range(3)]
    stable = [stability(ds, cfg, RESTART_SEEDS * r, f.labels, 1, 0.8) for r, f in enumerate(fits)]
    stable = [s["stability"] for s in stable]
    assert len(set(stable)) == 3, stable  # the choice is not a tie
    best = int(np.argmax(stable))
    assert kept.metrics["restart_kept"] == best
    assert kept.metrics["stability"] == pytest.approx(max(stable))
    # kept is the restart chosen, and repeatable: the fits above were made again, apart from it
    np.testing.assert_array_equal(kept.labels, fits[best].labels)
    one = cluster(ds, cfg.model_copy(update={"restarts": 1}), seed=0)  # no restarts: as before
    np.testing.assert_array_equal(one.labels, fits[0].labels)  # restart 0 is seed 0's fit
    assert "restart_kept" not in one.metrics


def test_the_consensus_of_noisy_partitions_finds_what_they_share(monkeypatch):
    """Eight partitions, each the styles with 35 % of the trajectories moved at random and its
    clusters renumbered: their consensus is the styles, also where only a sample is linked."""
    from pcpg_dist.stages.clustering import latent_start as L

    rng = np.random.default_rng(0)
    truth = np.repeat(np.arange(4), [150, 100, 60, 90])  # unequal styles
    parts = []
    for _ in range(8):
        p = truth.copy()
        moved = rng.random(len(p)) < 0.35
        p[moved] = rng.integers(0, 4, moved.sum())
        parts.append(rng.permutation(4)[p])
    parts = np.stack(parts)
    each = [clustering_metrics(truth, p)["accuracy"] for p in parts]
    assert max(each) < 0.8
    joined = L.consensus(parts, 4, seed=0)
    assert clustering_metrics(truth, joined)["accuracy"] >= 0.95
    monkeypatch.setattr(L, "CONSENSUS_LINKED", 120)  # a "large" log: 120 linked, 280 joined
    sampled = L.consensus(parts, 4, seed=0)
    assert clustering_metrics(truth, sampled)["accuracy"] >= 0.95
    np.testing.assert_array_equal(L.consensus(parts, 4, seed=0), sampled)


def test_latent_fits_side_by_side_each_follow_their_own_loss():
    """The batched fits share nothing: the gradient of their summed loss, in one fit's
    parameters, is that fit's own loss's gradient (so Adam moves each as if it were alone)."""
    from pcpg_dist.stages.clustering.latent_start import LatentPolicies

    gen = torch.Generator().manual_seed(0)
    rows, n = 64, 10
    s = torch.randn(rows, 5, generator=gen)
    a = torch.randint(3, (rows,), generator=gen)
    valid = torch.ones(rows, 3, dtype=torch.bool)
    traj = torch.randint(n, (rows,), generator=gen)
    net = LatentPolicies(5, n, 2, 8, 3, runs=3)
    net.reset_parameters(gen)
    noise = torch.randn(3, rows, 2, generator=gen)
    nll = net.step_nll(s, a, valid, traj, noise)
    assert nll.shape == (rows, 3) and (nll > 0).all()
    summed = torch.autograd.grad(nll.sum(), list(net.parameters()), retain_graph=True)
    alone = torch.autograd.grad(nll[:, 1].sum(), list(net.parameters()))
    for g_sum, g_one in zip(summed, alone, strict=True):
        torch.testing.assert_close(g_sum[1], g_one[1])
        assert (g_one[0] == 0).all() and (g_one[2] == 0).all()


def test_a_consensus_of_latent_fits_finds_the_styles_and_repeats_with_its_seed(goals):
    """``latent_runs``: fits side by side, k-means on each, their consensus."""
    from pcpg_dist.stages.clustering.latent_start import fit_latents, latent_start
    from pcpg_dist.stages.clustering.policy_mix import _policy_view

    set_threads(1)
    cfg = ClusterConfig(**FAST, latent_runs=4, latent_steps=150)
    inputs = _policy_view(goals, goals.states, cfg)[3]
    mu = fit_latents(inputs, goals.n_trajectories, cfg, goals.n_actions, torch.Generator())
    assert mu.shape == (4, goals.n_trajectories, cfg.latent_dims)
    assert not np.allclose(mu[0], mu[1])  # each fit its own
    start = latent_start(inputs, goals.n_trajectories, cfg, goals.n_actions, seed=0)
    assert clustering_metrics(goals.styles, start)["accuracy"] >= 0.9
    again = latent_start(inputs, goals.n_trajectories, cfg, goals.n_actions, seed=0)
    np.testing.assert_array_equal(again, start)
