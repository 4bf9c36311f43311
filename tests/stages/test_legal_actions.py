"""A few legal actions of many (board and card games): the policies score only the legal pairs,
with the dense softmax's values, and policy_mix finds styles told apart by which moves they make."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pcpg_dist.common.devices import set_threads
from pcpg_dist.dataset import Dataset
from pcpg_dist.stages import legal_share
from pcpg_dist.stages.clustering import (
    ClusterConfig,
    cluster,
    clustering_metrics,
    legal_actions,
    load_model,
)
from pcpg_dist.stages.clustering.latent_start import LatentPolicies, LatentPolicy
from pcpg_dist.stages.clustering.legal_actions import Legal, legal_pairs, sparse_pays
from pcpg_dist.stages.clustering.policy_network import PolicyMixture

N_ACTIONS, LEGAL = 96, 8


def sparse_rows(rows: int, gen: torch.Generator):
    """(valid, actions): LEGAL random legal actions of N_ACTIONS per row, one of them taken."""
    order = torch.rand(rows, N_ACTIONS, generator=gen).argsort(1)[:, :LEGAL]
    valid = torch.zeros(rows, N_ACTIONS, dtype=torch.bool).scatter_(1, order, True)
    return valid, order[:, 0]


def dense(monkeypatch):
    """The dense softmax whatever the mask (the path every small action space takes)."""
    monkeypatch.setattr(legal_share, "SPARSE_MIN_ACTIONS", 10**9)


def test_only_many_actions_with_few_legal_take_the_sparse_path():
    gen = torch.Generator().manual_seed(0)
    valid, _ = sparse_rows(50, gen)
    assert sparse_pays(valid)  # 8 of 96
    assert not sparse_pays(torch.ones(50, N_ACTIONS, dtype=torch.bool))  # every action legal
    assert not sparse_pays(valid[:, :39])  # Mario's 39 actions: dense, as before
    assert not sparse_pays(torch.zeros(0, N_ACTIONS, dtype=torch.bool))
    assert not sparse_pays(valid.to("meta"))  # off the CPU (a GPU): dense, the kernel is numba's


def test_legal_pairs_point_at_each_rows_taken_action():
    gen = torch.Generator().manual_seed(1)
    valid, actions = sparse_rows(30, gen)
    pairs = legal_pairs(valid, actions)
    assert len(pairs.row) == 30 * LEGAL and len(pairs.picked) == 30
    torch.testing.assert_close(pairs.row[pairs.picked], torch.arange(30))
    torch.testing.assert_close(pairs.action[pairs.picked], actions)
    assert bool(valid[pairs.row, pairs.action].all())


def test_the_latent_start_sees_only_the_ids_legal_somewhere_in_the_log():
    from pcpg_dist.stages.clustering.legal_actions import on_legal_ids

    gen = torch.Generator().manual_seed(2)
    valid, actions = sparse_rows(200, gen)
    valid[:, 90:] = False  # six ids never legal
    actions = torch.where(actions >= 90, torch.zeros_like(actions), actions)
    valid[torch.arange(200), actions] = True
    a, v, n = on_legal_ids(actions, valid, N_ACTIONS)
    kept = valid.any(0).nonzero().squeeze(1)
    assert n == len(kept) <= 90 and v.shape == (200, n)
    # every row keeps its legal moves, renumbered in order, and its taken one among them
    assert torch.equal(kept[v.nonzero()[:, 1]], valid.nonzero()[:, 1])
    assert torch.equal(kept[a], actions)
    dense = torch.ones(20, 5, dtype=torch.bool), torch.arange(20) % 5
    assert on_legal_ids(dense[1], dense[0], 5)[2] == 5  # a small action space: as it is


@pytest.mark.parametrize("net", ["mixture", "latent", "latents"])
def test_the_sparse_path_gives_the_dense_log_probs_and_gradients(monkeypatch, net):
    gen = torch.Generator().manual_seed(2)
    rows, dims = 40, 3
    valid, actions = sparse_rows(rows, gen)
    s = torch.randn(rows, 5, generator=gen)
    traj = torch.arange(rows) % 7
    if net == "mixture":
        model = PolicyMixture(5, 16, 3, N_ACTIONS)
        model.reset_parameters(gen)
        with torch.no_grad():  # default-initialised heads are near uniform: make them differ
            model.heads.weight.mul_(20)
        run = lambda v: model.step_log_probs(s, actions, v)  # noqa: E731
    elif net == "latent":
        model = LatentPolicy(5, 7, dims, 16, N_ACTIONS)
        model.reset_parameters(gen)
        z = torch.randn(rows, dims, generator=gen)
        run = lambda v: model.nll_given(s, actions, v, z)  # noqa: E731
    else:
        model = LatentPolicies(5, 7, dims, 16, N_ACTIONS, runs=2)
        model.reset_parameters(gen)
        noise = torch.randn(2, rows, dims, generator=gen)
        run = lambda v: model.step_nll(s, actions, v, traj, noise)  # noqa: E731

    def values_and_grads():
        model.zero_grad()
        out = run(valid)
        out.square().sum().backward()
        grads = [p.grad for p in model.parameters()]  # None: not used (nll_given's posteriors)
        return out.detach(), [torch.zeros(1) if g is None else g.clone() for g in grads]

    sparse, sparse_grads = values_and_grads()
    with monkeypatch.context() as m:
        dense(m)
        dense_out, dense_grads = values_and_grads()
    assert sparse.std() > 0.1  # not all alike
    torch.testing.assert_close(sparse, dense_out, rtol=1e-5, atol=1e-5)
    for got, want in zip(sparse_grads, dense_grads, strict=True):
        torch.testing.assert_close(got, want, rtol=1e-4, atol=1e-5)
    assert isinstance(legal_actions.as_legal(valid, actions), Legal)


def movers(n_per_style: int, seed: int) -> Dataset:
    """Three styles on a board of N_ACTIONS move ids, LEGAL legal per position: style c takes a
    legal move whose id is c mod 3 (80 %, else any legal move). The states are noise: only
    which moves are made tells the styles apart."""
    rng = np.random.default_rng(seed)
    trajs, styles = [], []
    for style in range(3):
        for _ in range(n_per_style):
            t = int(rng.integers(12, 30))
            valid = np.zeros((t, N_ACTIONS), bool)
            for row in valid:
                row[rng.choice(N_ACTIONS, LEGAL, replace=False)] = True
            actions = []
            for row in valid[:-1]:
                legal = np.flatnonzero(row)
                mine = legal[legal % 3 == style]
                pick = mine if len(mine) and rng.random() < 0.8 else legal
                actions.append(int(rng.choice(pick)))
            trajs.append(
                {
                    "states": rng.normal(size=(t, 4)),
                    "actions": np.array(actions),
                    "valid": valid,
                    "rewards": np.zeros(t - 1),
                }
            )
            styles.append(style)
    return Dataset.from_trajectories("toy", "movers", N_ACTIONS, trajs, styles, [True] * len(trajs))


def test_policy_mix_finds_styles_told_apart_by_their_moves_among_many(tmp_path):
    set_threads(1)
    ds = movers(25, seed=3)
    cfg = ClusterConfig(method="policy_mix", k=3, hidden_size=16, kmeans_n_init=4, latent_steps=100)
    found = cluster(ds, cfg, seed=0)
    assert clustering_metrics(ds.styles, found.labels)["accuracy"] >= 0.9
    np.testing.assert_array_equal(cluster(ds, cfg, seed=0).labels, found.labels)
    found.model.save(tmp_path / "m")  # `pcpg classify` scores a new log the same way
    fresh = movers(8, seed=4)
    assert (
        clustering_metrics(fresh.styles, load_model(tmp_path / "m").predict(fresh))["accuracy"]
        >= 0.9
    )


def test_a_profile_of_many_actions_keeps_the_most_taken_and_pools_the_rest():
    from pcpg_dist.stages.clustering.profile import MAX_ACTIONS, trajectory_profiles

    ds = movers(6, seed=5)  # 96 actions: more than MAX_ACTIONS
    d = min(4, ds.states.shape[1])
    profiles = trajectory_profiles(ds)
    n_cols = MAX_ACTIONS + 1
    assert profiles.shape == (ds.n_trajectories, n_cols + 1 + 3 * d + MAX_ACTIONS * d + 2)
    steps = ds.actions >= 0
    top = np.argmax(np.bincount(ds.actions[steps], minlength=N_ACTIONS))  # column 0
    for i in range(ds.n_trajectories):
        mine = ds.actions[ds.offsets[i] : ds.offsets[i + 1]]
        mine = mine[mine >= 0]
        assert profiles[i, 0] == pytest.approx(np.mean(mine == top))
    np.testing.assert_allclose(profiles[:, :n_cols].sum(1), 1.0)  # every action counted once
    few_actions = np.where(ds.actions >= 0, ds.actions % 39, -1)
    few = Dataset.from_trajectories(
        "toy",
        "few",
        39,
        [
            {
                "states": ds.states[ds.offsets[i] : ds.offsets[i + 1]],
                "actions": few_actions[ds.offsets[i] : ds.offsets[i + 1] - 1],
                "valid": np.ones((ds.lengths[i], 39), bool),  # lengths: states, actions + 1
                "rewards": np.zeros(ds.lengths[i] - 1),
            }
            for i in range(ds.n_trajectories)
        ],
        ds.styles,
        [True] * ds.n_trajectories,
    )
    assert trajectory_profiles(few).shape[1] == 39 + 1 + 3 * d + 39 * d + 2
