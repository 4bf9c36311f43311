"""Rolling agents out in a Gymnasium environment (trajectories.gymnasium_env), on toy-text envs."""

from __future__ import annotations

from collections import deque

import gymnasium
import numpy as np
import pytest
from gymnasium import spaces

from pcpg_dist.common.errors import ConfigError
from pcpg_dist.domains.base import random_policy
from pcpg_dist.domains.trajectories.gym_rollout import check_compatible, make_env, rollout

LAKE = {"is_slippery": False, "map_name": "4x4"}
LEFT, DOWN, RIGHT, UP = 0, 1, 2, 3  # FrozenLake's actions
LAKE_ACTIONS = ("left", "down", "right", "up")


def lake_plan(desc: np.ndarray) -> np.ndarray:
    """The first action of a shortest path to G from every cell of a non-slippery lake (BFS from G)."""
    rows, cols = desc.shape
    plan = np.full(rows * cols, -1, np.int64)
    goal = next((r, c) for r in range(rows) for c in range(cols) if desc[r, c] == b"G")
    seen, queue = {goal}, deque([goal])
    # the move that enters (r, c) from its neighbour (r - dr, c - dc)
    moves = {LEFT: (0, -1), DOWN: (1, 0), RIGHT: (0, 1), UP: (-1, 0)}
    while queue:
        r, c = queue.popleft()
        for a, (dr, dc) in moves.items():
            pr, pc = r - dr, c - dc
            if 0 <= pr < rows and 0 <= pc < cols and (pr, pc) not in seen and desc[pr, pc] != b"H":
                seen.add((pr, pc))
                plan[pr * cols + pc] = a
                queue.append((pr, pc))
    return plan


@pytest.fixture(scope="module")
def lake_policy():
    env = make_env("FrozenLake-v1", LAKE)
    plan = lake_plan(env.unwrapped.desc)
    env.close()

    def policy(states, valid, rng):
        return plan[np.argmax(states, axis=1)]  # states are one-hot cells

    return policy


def returns(ds) -> np.ndarray:
    return np.add.reduceat(ds.rewards, ds.offsets[:-1])


# ------------------------------------------------------------------ (a) FrozenLake
def test_scripted_optimal_policy_reaches_the_goal_in_six_steps(lake_policy, rng):
    ds = rollout(
        "FrozenLake-v1", LAKE, lake_policy, 10, rng, max_steps=100, action_names=LAKE_ACTIONS
    )
    assert (ds.domain, ds.env, ds.n_actions, ds.state_dim) == (
        "trajectories",
        "FrozenLake-v1",
        4,
        16,
    )
    assert (ds.lengths - 1 == 6).all()
    np.testing.assert_array_equal(returns(ds), 1.0)
    assert ds.success.all()
    assert (ds.styles == -1).all() and np.isnan(ds.epsilon).all()
    # states are one-hot cells: start (0, 0), goal (3, 3)
    first, last = ds.states[ds.offsets[:-1]], ds.states[ds.offsets[1:] - 1]
    assert (first.sum(axis=1) == 1).all() and (first[:, 0] == 1).all() and (last[:, 15] == 1).all()
    # a deterministic lake: every episode takes the same six actions
    np.testing.assert_array_equal(ds.actions.reshape(10, 7), np.tile(ds.actions[:7], (10, 1)))
    assert ds.valid.all()  # FrozenLake gives no action mask


def test_random_policy_mostly_fails_and_what_success_means(rng):
    ds = rollout("FrozenLake-v1", LAKE, random_policy, 60, rng, max_steps=100)
    reached = returns(ds) > 0
    assert reached.mean() < 0.2
    # default rule: the env ended the episode itself, which on FrozenLake includes the holes
    final = ds.states[ds.offsets[1:] - 1].argmax(axis=1)
    np.testing.assert_array_equal(ds.success, np.isin(final, [5, 7, 11, 12, 15]))
    assert ds.success.mean() > 0.8
    strict = rollout(
        "FrozenLake-v1",
        LAKE,
        random_policy,
        60,
        np.random.default_rng(12345),
        max_steps=100,
        success_rule="terminated_positive_reward",
    )
    np.testing.assert_array_equal(strict.success, reached)


def test_max_steps_ends_an_episode_without_success(rng):
    def left(states, valid, rng):  # bumps into the start cell's wall forever
        return np.zeros(len(states), np.int64)

    ds = rollout("FrozenLake-v1", LAKE, left, 3, rng, max_steps=7)
    assert (ds.lengths - 1 == 7).all() and not ds.success.any()
    # the env's own time limit (100 for FrozenLake) truncates: not a success either
    ds = rollout("FrozenLake-v1", LAKE, left, 2, rng, max_steps=500)
    assert (ds.lengths - 1 == 100).all() and not ds.success.any()


# ------------------------------------------------------------------ (b) seeding
def test_same_rng_same_dataset():
    slippery = {"is_slippery": True, "map_name": "4x4"}  # the env's transitions use its seed
    a = rollout(
        "FrozenLake-v1", slippery, random_policy, 12, np.random.default_rng(7), max_steps=40
    )
    b = rollout(
        "FrozenLake-v1", slippery, random_policy, 12, np.random.default_rng(7), max_steps=40
    )
    c = rollout(
        "FrozenLake-v1", slippery, random_policy, 12, np.random.default_rng(8), max_steps=40
    )
    for field in ("states", "actions", "rewards", "valid", "offsets", "success"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert a.n_rows != c.n_rows or not np.array_equal(a.actions, c.actions)


# ------------------------------------------------------------------ (c, d) Taxi's action mask
def test_taxi_action_mask_is_the_valid_mask(rng):
    seen = []

    def recording(states, valid, rng):
        a = random_policy(states, valid, rng)
        seen.append((valid.copy(), a))
        return a

    ds = rollout("Taxi-v4", {}, recording, 6, rng, max_steps=40)
    assert ds.state_dim == 500 and ds.n_actions == 6
    taxi = gymnasium.make("Taxi-v4").unwrapped
    expected = np.stack([taxi.action_mask(int(s)).astype(bool) for s in ds.states.argmax(axis=1)])
    np.testing.assert_array_equal(ds.valid, expected)
    assert not ds.valid.all()  # the mask does mask something
    for valid, a in seen:
        assert valid[np.arange(len(a)), a].all()
    assert sum(len(a) for _, a in seen) == ds.n_rows - ds.n_trajectories
    rows = ds.step_rows
    assert ds.valid[rows, ds.actions[rows]].all()


def test_invalid_action_names_episode_and_step(rng):
    calls = []

    def bad_at_step_two(states, valid, rng):
        a = np.argmax(valid, axis=1)
        calls.append(len(states))
        if len(calls) == 3:  # Taxi cannot finish in 2 steps: all 4 episodes are still live
            a[1] = int(np.argmin(valid[1]))  # a masked action
        return a

    with pytest.raises(
        ValueError, match=r"episode 1, step 2: the policy chose action \d, which is not valid"
    ):
        rollout("Taxi-v4", {}, bad_at_step_two, 4, rng, max_steps=10)

    def out_of_range(states, valid, rng):
        return np.full(len(states), 6)

    with pytest.raises(ValueError, match="episode 0, step 0: the policy chose action 6"):
        rollout("Taxi-v4", {}, out_of_range, 2, rng, max_steps=10)


# ------------------------------------------------------------------ (e) config errors
def _one_line(err: pytest.ExceptionInfo) -> str:
    msg = str(err.value)
    assert "\n" not in msg
    return msg


def test_check_compatible_rejects_other_widths():
    env = make_env("FrozenLake-v1", LAKE)
    check_compatible(env, 16, 4)
    with pytest.raises(ConfigError) as err:
        check_compatible(env, 2, 4)
    msg = _one_line(err)
    assert "trajectories.gymnasium_env" in msg and "16 features" in msg and "2 state columns" in msg
    with pytest.raises(ConfigError) as err:
        check_compatible(env, 16, 5)
    assert "4 actions" in _one_line(err) and "have 5" in str(err.value)


def test_make_env_errors():
    with pytest.raises(
        ConfigError, match="trajectories.gymnasium_env.*Did you mean: `FrozenLake`"
    ) as err:
        make_env("FrozenLak-v1", {})
    _one_line(err)
    with pytest.raises(ConfigError, match="trajectories.gymnasium_env.*Please use `Taxi-v4`"):
        make_env("Taxi-v3", {"is_rainy": False})  # retired in Gymnasium 1.x
    # a namespace a package registers on import (ALE, in a process that has not imported ale_py)
    with pytest.raises(ConfigError, match=r"Namespace NoSuchPkg not found.*package first") as err:
        make_env("NoSuchPkg/Game-v0", {})
    _one_line(err)
    with pytest.raises(ConfigError, match="trajectories.gymnasium_kwargs.*slipery"):
        make_env("FrozenLake-v1", {"is_slipery": False})
    with pytest.raises(ConfigError, match="trajectories.gymnasium_kwargs.*5x5"):
        make_env("FrozenLake-v1", {"map_name": "5x5"})
    with pytest.raises(ConfigError, match=r"Pendulum-v1 has action space Box\(") as err:
        make_env("Pendulum-v1", {})
    _one_line(err)


# ------------------------------------------------------------------ Discrete(n, start=s)
class Corridor(gymnasium.Env):
    """Cells 0..4 from 0 to the goal 4; moves -1, 0, +1: Discrete(3, start=-1), so logged action
    2 is +1. Observations are Discrete(5, start=10): the one-hot index is cell = obs - 10."""

    observation_space = spaces.Discrete(5, start=10)
    action_space = spaces.Discrete(3, start=-1)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.cell = 0
        return 10, {}

    def step(self, action):
        if action not in (-1, 0, 1):
            raise ValueError(f"Corridor got action {action}")
        self.cell = min(max(self.cell + action, 0), 4)
        done = self.cell == 4
        return 10 + self.cell, float(done), done, False, {}


CORRIDOR = "pcpg-test/Corridor-v0"
if CORRIDOR not in gymnasium.registry:
    gymnasium.register(CORRIDOR, entry_point=Corridor, max_episode_steps=50)


def test_discrete_start_maps_logged_actions(rng):
    def forward(states, valid, rng):
        return np.full(len(states), 2, np.int64)  # logged action 2 = env action +1

    ds = rollout(CORRIDOR, {}, forward, 2, rng, max_steps=20)
    assert ds.env == "pcpg-test_Corridor-v0" and ds.n_actions == 3
    assert (ds.lengths - 1 == 4).all() and ds.success.all()
    np.testing.assert_array_equal(ds.trajectory_states(0).argmax(axis=1), [0, 1, 2, 3, 4])
    np.testing.assert_array_equal(ds.actions[:4], 2)
    check_compatible(make_env(CORRIDOR, {}), 5, 3)


# ------------------------------------------------------------------ an env that fails when it runs
class Fragile(Corridor):
    """The corridor, but ``fail_in`` ("reset" or "step", from the ``at_step``-th step on) raises a
    two-line error, as a missing renderer would; only action +1 (logged 2) is valid, by the mask."""

    def __init__(self, fail_in: str = "never", at_step: int = 0):
        self.fail_in, self.at_step = fail_in, at_step

    def reset(self, *, seed=None, options=None):
        if self.fail_in == "reset":
            raise RuntimeError("no display found\nsecond line of the env's error")
        self.steps = 0
        obs, _ = super().reset(seed=seed)
        return obs, {"action_mask": np.array([0, 0, 1], np.int8)}

    def step(self, action):
        if action != 1:
            raise ValueError(f"Fragile got action {action}, which its mask forbids")
        if self.fail_in == "step" and self.steps >= self.at_step:
            raise RuntimeError("no display found\nsecond line of the env's error")
        self.steps += 1
        obs, reward, done, truncated, _ = super().step(action)
        return obs, reward, done, truncated, {"action_mask": np.array([0, 0, 1], np.int8)}


FRAGILE = "pcpg-test/Fragile-v0"
if FRAGILE not in gymnasium.registry:
    gymnasium.register(FRAGILE, entry_point=Fragile, max_episode_steps=50)


def _corridor_config(tmp_path, kwargs: dict):
    import pandas as pd
    import yaml

    rows = [
        {
            "trajectory": i,
            "t": t,
            **{f"s{j}": float(j == t) for j in range(5)},
            "action": 2 if t < 4 else -1,
        }
        for i in range(4)
        for t in range(5)
    ]
    pd.DataFrame(rows).to_parquet(tmp_path / "corridor.parquet", index=False)
    path = tmp_path / "cfg.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "name": "corridor",
                "domain": "trajectories",
                "seeds": [0],
                "trajectories": {
                    "path": "corridor.parquet",
                    "gymnasium_env": FRAGILE,
                    "gymnasium_kwargs": kwargs,
                },
            }
        )
    )
    return path


@pytest.mark.parametrize("fail_in", ["reset", "step"])
def test_kwargs_that_fail_only_when_the_env_runs_fail_at_config_load(fail_in, tmp_path, capsys):
    """(Was: `render_mode: human` without pygame failed in the rollouts, after data, clustering and
    training, with an 83-line Ray traceback.)"""
    from pcpg_dist.cli import main
    from pcpg_dist.config import load_config

    load_config(
        _corridor_config(tmp_path, {"fail_in": "step", "at_step": 1})
    )  # one reset, one masked step
    cfg = _corridor_config(tmp_path, {"fail_in": fail_in})
    code = main(["run", str(cfg), "--no-tracking", "--quiet", "--workdir", str(tmp_path / "runs")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert err.startswith(
        f"pcpg: error: {cfg}: key 'trajectories.gymnasium_kwargs': gymnasium.make("
        f"'{FRAGILE}', **{{'fail_in': '{fail_in}'}}) fails on its first reset() and step(): "
        f"RuntimeError: no display found"
    ), err
    assert "second line" not in err and not (tmp_path / "runs").exists()


def test_an_env_error_during_rollouts_is_one_config_error_naming_the_env(rng):
    def forward(states, valid, rng):
        return np.full(len(states), 2, np.int64)

    with pytest.raises(ConfigError) as err:
        rollout(FRAGILE, {"fail_in": "step", "at_step": 2}, forward, 2, rng, max_steps=10)
    assert _one_line(err) == (
        f"key 'trajectories.gymnasium_kwargs': gymnasium.make('{FRAGILE}', **{{'at_step': 2, "
        f"'fail_in': 'step'}}) failed in a rollout (episode 0, step 2, step()): "
        f"RuntimeError: no display found"
    )


# ------------------------------------------------------------------ (f) learning end to end
def test_bc_agent_trained_on_lake_logs_reaches_the_goal(lake_policy, rng):
    from pcpg_dist.config.stages import BCConfig
    from pcpg_dist.domains.defaults import split_trajectories
    from pcpg_dist.stages.bc import train_cells
    from pcpg_dist.stages.ranking import RankConfig, plan_cells

    def noisy_expert(states, valid, rng):  # logs that also visit cells off the optimal path
        a = lake_policy(states, valid, rng)
        explore = rng.random(len(a)) < 0.2
        return np.where(explore, random_policy(states, valid, rng), a)

    logs = rollout(
        "FrozenLake-v1",
        LAKE,
        noisy_expert,
        60,
        rng,
        max_steps=30,
        success_rule="terminated_positive_reward",
    )
    assert 0.5 < logs.success.mean() < 1.0  # the logs hold failures too
    tr, _ = split_trajectories(logs.n_trajectories, 0.2, 0)
    cells = plan_cells(
        logs,
        np.zeros(logs.n_trajectories, np.int64),
        tr,
        RankConfig(ps=(1.0,)),
        seeds=[0],
        baseline=False,
    )
    trained = train_cells(cells, BCConfig(epochs=600))
    ds = rollout("FrozenLake-v1", LAKE, trained.policy("k0-p1-s0"), 20, rng, max_steps=100)
    assert (returns(ds) == 1.0).mean() >= 0.9


# ------------------------------------------------------------------ survival: reached_time_limit
def test_reached_time_limit_counts_truncation_and_max_steps_but_not_termination(rng):
    def balance(states, valid, rng):  # CartPole's angle PD controller: the pole stays up
        return (states[:, 2] + 0.3 * states[:, 3] > 0).astype(np.int64)

    def push_left(states, valid, rng):  # the pole falls: the env terminates
        return np.zeros(len(states), np.int64)

    rule = "reached_time_limit"
    cut = rollout("CartPole-v1", {}, balance, 2, rng, max_steps=50, success_rule=rule)
    assert (cut.lengths - 1 == 50).all() and cut.success.all()  # ended by max_steps, alive
    limited = rollout(
        "CartPole-v1", {"max_episode_steps": 60}, balance, 2, rng, max_steps=100, success_rule=rule
    )
    assert (limited.lengths - 1 == 60).all() and limited.success.all()  # truncated by the env
    fallen = rollout("CartPole-v1", {}, push_left, 2, rng, max_steps=100, success_rule=rule)
    assert (fallen.lengths - 1 < 100).all() and not fallen.success.any()
    default = rollout("CartPole-v1", {}, balance, 2, rng, max_steps=50)
    assert not default.success.any()  # 'terminated' never counts a survivor
    with pytest.raises(ValueError, match="'reached_time_limit', got 'survived'"):
        rollout("CartPole-v1", {}, balance, 1, rng, max_steps=5, success_rule="survived")
