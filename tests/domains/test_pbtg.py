"""PBTG: Q-learning reaches the value-iteration optimum; sampling is seeded and key-determined."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pcpg_dist.domains.gridworld import layout as gw
from pcpg_dist.domains.gridworld.pbtg import (
    PBTGConfig,
    assemble_dataset,
    generate_pair,
    q_learning,
    sample_trajectories,
)

LAYOUTS = Path(__file__).resolve().parents[2] / "pcpg_dist" / "data" / "gridworld"


@pytest.mark.parametrize("env", ["E1", "E2", "E3", "E4", "E5"])
def test_q_learning_greedy_policy_is_optimal_for_every_reward(env):
    layout = gw.load_layout(LAYOUTS / f"{env}.txt")
    t = layout.tables
    for r in range(4):
        q = q_learning(t, r, PBTGConfig(), seed=7 + r)
        route = gw.greedy_route(t, gw.greedy_actions(q, t.valid))
        assert gw.route_return(t, route, r) == gw.optimal_return(layout, r), f"{env} R{r + 1}"


def test_noiseless_rollouts_follow_the_style():
    layout = gw.load_layout(LAYOUTS / "E1.txt")
    cfg = PBTGConfig(noise_min=0.0, noise_max=0.0, trajectories_per_style=20, dataset_per_style=20)
    for r in range(4):
        q = q_learning(layout.tables, r, cfg, seed=1)
        ds = sample_trajectories(layout, q, r, 20, cfg, np.random.default_rng(0))
        assert ds.success.all()
        last = ds.states[ds.offsets[1:] - 1]
        assert {tuple(v) for v in last[:, 2:].astype(int)} == {gw.SIGNATURES[r]}
        assert len(set(ds.lengths)) == 1  # deterministic policy, no noise: one route


def test_noise_lowers_skill_and_is_recorded():
    layout = gw.load_layout(LAYOUTS / "E2.txt")
    cfg = PBTGConfig(
        noise_min=0.0, noise_max=0.3, trajectories_per_style=2000, dataset_per_style=500
    )
    q = q_learning(layout.tables, 3, cfg, seed=1)
    ds = sample_trajectories(layout, q, 3, 2000, cfg, np.random.default_rng(0))
    assert ((ds.epsilon >= 0) & (ds.epsilon <= 0.3)).all()
    low, high = ds.epsilon < 0.1, ds.epsilon > 0.2
    # Noisier trajectories are longer and reach G less often.
    assert ds.lengths[high].mean() > ds.lengths[low].mean()
    assert ds.success[high].mean() <= ds.success[low].mean()


def test_generate_pair_is_a_function_of_its_key():
    layout = gw.load_layout(LAYOUTS / "E3.txt")
    cfg = PBTGConfig(episodes=3000, trajectories_per_style=300, dataset_per_style=100)
    a, b = generate_pair(layout, 2, cfg, base_seed=5), generate_pair(layout, 2, cfg, base_seed=5)
    c = generate_pair(layout, 2, cfg, base_seed=6)
    assert a.n_trajectories == 100 and (a.styles == 2).all()
    for name in ("states", "actions", "valid", "rewards", "offsets", "epsilon"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.epsilon, c.epsilon)
    d = assemble_dataset([generate_pair(layout, r, cfg, 5) for r in (3, 1, 0, 2)])
    assert list(np.unique(d.styles, return_counts=True)[1]) == [100] * 4
    assert (np.diff(d.styles) >= 0).all() and (d.trajectory_ids == np.arange(400)).all()


@pytest.mark.parametrize(
    "bad",
    [
        {"noise_min": 0.5, "noise_max": 0.1},
        {"dataset_per_style": 9, "trajectories_per_style": 5},
        {"gamma": 0.0},
        {"episodes": 0},
    ],
)
def test_bad_pbtg_config_rejected(bad):
    with pytest.raises(ValueError):
        PBTGConfig(**bad)
