"""Minari <-> pcpg (pcpg_dist.domains.trajectories.minari_io), checked with the minari library itself."""

from __future__ import annotations

import os
from pathlib import Path

import gymnasium as gym
import minari
import numpy as np
import pyarrow as pa
import pytest
from minari.data_collector import EpisodeBuffer

from pcpg_dist.cli import main
from pcpg_dist.common.errors import DataError
from pcpg_dist.config import ExperimentConfig
from pcpg_dist.dataset import Dataset, write_datasets
from pcpg_dist.domains.trajectories.minari_io import (
    env_name,
    export_ids,
    find_dataset_folder,
    write_minari,
)
from pcpg_dist.domains.trajectories.minari_read import (
    flatten_observations,
    observation_names,
    read_minari,
)
from pcpg_dist.domains.trajectories.minari_stream import minari_stream_source

N_ACTIONS = 5


@pytest.fixture(autouse=True)
def minari_root(tmp_path, monkeypatch):
    """Every test reads and writes Minari datasets under tmp_path, never ~/.minari."""
    root = tmp_path / "minari"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    return root


def pcpg_dataset(
    rng: np.random.Generator, env: str = "lvl", lengths=(0, 2, 5, 9, 1), d: int = 3
) -> Dataset:
    """Trajectories of different numbers of steps (one with no action at all), valid masks that hold the
    taken action, styles 0/1 and both outcomes."""
    trajs = []
    for steps in lengths:
        actions = rng.integers(0, N_ACTIONS, steps)
        valid = rng.random((steps + 1, N_ACTIONS)) < 0.5
        valid[np.arange(steps), actions] = True
        trajs.append(
            {
                "states": rng.normal(size=(steps + 1, d)),
                "actions": actions,
                "valid": valid,
                "rewards": rng.normal(size=steps),
            }
        )
    n = len(lengths)
    return Dataset.from_trajectories(
        "trajectories",
        env,
        N_ACTIONS,
        trajs,
        styles=np.arange(n) % 2,
        success=np.arange(n) % 3 != 1,
        feature_names=tuple(f"f{j}" for j in range(d)),
    )


def rows_of(table: pa.Table, name: str) -> np.ndarray:
    return table.column(name).to_numpy(zero_copy_only=False)


def test_round_trip_through_minari(rng, tmp_path, minari_root):
    ds = pcpg_dataset(rng)
    written = write_minari({"lvl": ds}, minari_root, "pcpg/demo-v0")
    assert written == {"pcpg/demo-v0": minari_root / "pcpg/demo-v0"}

    # what the minari library itself sees
    loaded = minari.load_dataset("pcpg/demo-v0")
    assert loaded.total_episodes == ds.n_trajectories
    assert loaded.total_steps == ds.n_rows - ds.n_trajectories
    assert loaded.action_space == gym.spaces.Discrete(N_ACTIONS)
    assert loaded.observation_space == gym.spaces.Box(-np.inf, np.inf, (3,), np.float32)
    for i, ep in enumerate(loaded.iterate_episodes()):
        lo, hi = ds.offsets[i], ds.offsets[i + 1]
        assert ep.id == i
        np.testing.assert_array_equal(ep.observations, ds.states[lo:hi])
        np.testing.assert_array_equal(ep.actions, ds.actions[lo : hi - 1])
        np.testing.assert_array_equal(ep.rewards, ds.rewards[lo : hi - 1])
        if hi - lo > 1:
            assert ep.terminations[-1] == ds.success[i] and ep.truncations[-1] == (
                not ds.success[i]
            )
            assert not ep.terminations[:-1].any() and not ep.truncations[:-1].any()
        np.testing.assert_array_equal(ep.infos["style"], np.full(hi - lo, ds.styles[i]))
        np.testing.assert_array_equal(ep.infos["valid"], ds.valid[lo:hi])

    # and back as a step table: the same rows as the original
    table, meta = read_minari("pcpg/demo-v0")
    original = ds.to_table()
    for col in ("trajectory", "t", "action", "reward", "style", "s0", "s1", "s2"):
        np.testing.assert_array_equal(rows_of(table, col), rows_of(original, col), err_msg=col)
    np.testing.assert_array_equal(
        table.column("valid").combine_chunks().flatten().to_numpy(zero_copy_only=False),
        ds.valid.reshape(-1),
    )
    # success survives for every trajectory that took an action (Minari keeps it on the last step)
    stepped = np.repeat(ds.lengths > 1, ds.lengths)
    np.testing.assert_array_equal(
        rows_of(table, "success")[stepped], rows_of(original, "success")[stepped]
    )
    assert not rows_of(table, "success")[~stepped].any()
    assert set(rows_of(table, "env")) == {"pcpg_demo-v0"}
    assert table.schema.field("s0").type == pa.float32()
    assert meta["n_actions"] == N_ACTIONS and meta["feature_names"] == ["f0", "f1", "f2"]
    assert meta["pcpg"]["env"] == "lvl" and meta["env_spec"] is None
    assert meta["total_episodes"] == 5 and meta["total_steps"] == ds.n_rows - 5


def test_several_envs_give_one_minari_dataset_each(rng, minari_root):
    a, b = pcpg_dataset(rng, "a.1"), pcpg_dataset(rng, "b+2", lengths=(3, 3), d=2)
    written = write_minari({"a.1": a, "b+2": b}, minari_root, "pcpg/two-v3")
    assert sorted(written) == ["pcpg/two/a_1-v3", "pcpg/two/b_2-v3"]
    assert minari.load_dataset("pcpg/two/b_2-v3").observation_space.shape == (2,)
    table, meta = read_minari("pcpg/two/a_1-v3")
    np.testing.assert_array_equal(rows_of(table, "s1"), a.states[:, 1])
    assert meta["pcpg"]["env"] == "a.1"
    # Minari never overwrites; neither does the export, and it checks before writing anything
    c = pcpg_dataset(rng, "c")
    with pytest.raises(DataError, match="already exists"):
        write_minari({"c": c, "a.1": a}, minari_root, "pcpg/two-v3")
    assert not (minari_root / "pcpg/two/c-v3").exists()


def frozen_lake_like(dataset_id: str, styles: bool) -> list[list[int]]:
    """A Discrete(16)-observation, Discrete(4)-action dataset made with minari's own API."""
    rng = np.random.default_rng(7)
    buffers, observations = [], []
    for i, steps in enumerate((3, 6)):
        obs = rng.integers(0, 16, steps + 1).tolist()
        infos = {"style": [i] * (steps + 1)} if styles else None
        buffers.append(
            EpisodeBuffer(
                observations=obs,
                actions=rng.integers(0, 4, steps).tolist(),
                rewards=[0.0] * (steps - 1) + [1.0],
                terminations=[False] * (steps - 1) + [True],
                truncations=[False] * steps,
                infos=infos,
            )
        )
        observations.append(obs)
    with pytest.warns(UserWarning):  # minari nags about the unset author, description, ...
        minari.create_dataset_from_buffers(
            dataset_id,
            buffers,
            observation_space=gym.spaces.Discrete(16),
            action_space=gym.spaces.Discrete(4),
            data_format="arrow",
        )
    return observations


def test_discrete_observations_become_one_hot_states():
    observations = frozen_lake_like("toy/lake-v0", styles=True)
    table, meta = read_minari("toy/lake-v0")
    states = np.stack([rows_of(table, f"s{j}") for j in range(16)], axis=1)
    np.testing.assert_array_equal(
        states, np.eye(16, dtype=np.float32)[np.concatenate(observations)]
    )
    assert meta["n_actions"] == 4 and meta["feature_names"][:2] == ["obs=0", "obs=1"]
    np.testing.assert_array_equal(rows_of(table, "action")[[3, 10]], [-1, -1])
    np.testing.assert_array_equal(rows_of(table, "style"), [0] * 4 + [1] * 7)
    np.testing.assert_array_equal(rows_of(table, "success"), [True] * 11)
    np.testing.assert_array_equal(rows_of(table, "reward"), [0, 0, 1, 0, 0, 0, 0, 0, 0, 1, 0])
    assert "valid" not in table.column_names

    frozen_lake_like("toy/lake-v1", styles=False)
    assert "style" not in read_minari("toy/lake-v1")[0].column_names


def test_flatten_matches_gymnasium_for_nested_spaces():
    space = gym.spaces.Dict(
        {
            "pos": gym.spaces.Box(-1, 1, (2, 3), np.float32),
            "room": gym.spaces.Discrete(4, start=1),
            "bag": gym.spaces.Tuple((gym.spaces.MultiDiscrete([2, 3]), gym.spaces.MultiBinary(3))),
        }
    )
    space.seed(3)
    samples = [space.sample() for _ in range(20)]
    batch = {
        "pos": np.stack([s["pos"] for s in samples]),
        "room": np.array([s["room"] for s in samples]),
        "bag": (np.stack([s["bag"][0] for s in samples]), np.stack([s["bag"][1] for s in samples])),
    }
    expected = np.stack([gym.spaces.flatten(space, s) for s in samples]).astype(np.float32)
    np.testing.assert_array_equal(flatten_observations(space, batch), expected)
    names = observation_names(space)
    assert len(names) == gym.spaces.flatdim(space)
    # gymnasium's Dict sorts its keys: bag, pos, room
    assert names[:5] == [
        "obs.bag.0[0]=0",
        "obs.bag.0[0]=1",
        "obs.bag.0[1]=0",
        "obs.bag.0[1]=1",
        "obs.bag.0[1]=2",
    ]
    assert names[8:10] == ["obs.pos[0,0]", "obs.pos[0,1]"] and names[-1] == "obs.room=4"

    # the same through a Minari dataset written with that space
    buffer = EpisodeBuffer(
        observations=batch,
        actions=list(range(19)),
        rewards=[0.0] * 19,
        terminations=[False] * 19,
        truncations=[True] * 19,
    )
    with pytest.warns(UserWarning):
        minari.create_dataset_from_buffers(
            "toy/nested-v0",
            [buffer],
            observation_space=space,
            action_space=gym.spaces.Discrete(19),
            data_format="arrow",
        )
    table, meta = read_minari("toy/nested-v0")
    states = np.stack([rows_of(table, f"s{j}") for j in range(len(names))], axis=1)
    np.testing.assert_array_equal(states, expected)
    assert meta["feature_names"] == names and not rows_of(table, "success").any()


def test_continuous_actions_and_unknown_ids_are_one_line_errors(minari_root):
    buffer = EpisodeBuffer(
        observations=np.zeros((3, 2), np.float32),
        actions=np.zeros((2, 1), np.float32),
        rewards=[0.0, 0.0],
        terminations=[False, True],
        truncations=[False, False],
    )
    with pytest.warns(UserWarning):
        minari.create_dataset_from_buffers(
            "toy/reacher-v0",
            [buffer],
            observation_space=gym.spaces.Box(-1, 1, (2,), np.float32),
            action_space=gym.spaces.Box(-1, 1, (1,), np.float32),
            data_format="arrow",
        )
    with pytest.raises(DataError, match=r"pcpg needs a discrete action space") as err:
        read_minari("toy/reacher-v0")
    assert "Box(" in str(err.value)
    streamed = ExperimentConfig.model_validate(  # streamed: the same line, before any task
        {"name": "r", "domain": "trajectories",
         "trajectories": {"path": "minari:toy/reacher-v0", "stream": "on"}}
    )  # fmt: skip
    with pytest.raises(DataError, match=r"pcpg needs a discrete action space"):
        minari_stream_source(streamed.trajectories, "r")

    with pytest.raises(DataError) as err:
        read_minari("toy/reacher-v1")
    msg = str(err.value)
    assert "\n" not in msg and "toy/reacher-v1" in msg and str(minari_root) in msg
    assert "minari download" in msg and "toy/reacher-v0" in msg  # the close local one
    with pytest.raises(DataError, match="not a Minari dataset id"):
        read_minari("../../etc")


def test_ids_and_env_names():
    assert env_name("D4RL/door/human-v0") == "D4RL_door_human-v0"
    assert export_ids("mine-v2", ["x"]) == {"x": "mine-v2"}
    assert export_ids("ns/mine-v2", ["x", "y.z"]) == {"x": "ns/mine/x-v2", "y.z": "ns/mine/y_z-v2"}
    for bad in ("ns/mine", "ns/mine v0-v0", "/abs-v0"):
        with pytest.raises(DataError, match="not a Minari dataset id"):
            export_ids(bad, ["x"])


def test_cli_exports_a_dataset_folder_and_a_runs_cached_data(rng, tmp_path, minari_root, capsys):
    ds = pcpg_dataset(rng)
    data = tmp_path / "mydata"
    write_datasets(data, [ds], {"source": "test"})
    assert main(["export", "minari", str(data), "--out", str(minari_root)]) == 0
    out = capsys.readouterr().out
    assert "pcpg/mydata-v0" in out and "5 episodes" in out
    np.testing.assert_array_equal(rows_of(read_minari("pcpg/mydata-v0")[0], "action"), ds.actions)

    # a run folder: the newest cached data folder is the one exported
    run = tmp_path / "runs" / "exp1"
    old, new = run / "cache/data/aaa", run / "cache/data/bbb"
    write_datasets(old, [pcpg_dataset(rng, "old")], {})
    write_datasets(new, [pcpg_dataset(rng, "new"), pcpg_dataset(rng, "new2")], {})
    os.utime(old / "manifest.json", (1e9, 1e9))
    assert find_dataset_folder(run) == new
    assert (
        main(["export", "minari", str(run), "--out", str(minari_root), "--dataset-id", "me/run-v1"])
        == 0
    )
    out = capsys.readouterr().out
    assert "me/run/new-v1" in out and "me/run/new2-v1" in out
    assert minari.load_dataset("me/run/new2-v1").total_episodes == 5

    # a folder with no data: exit 2 and one line
    assert main(["export", "minari", str(tmp_path / "runs"), "--out", str(minari_root)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "manifest.json" in err


def test_an_interrupted_export_leaves_nothing_and_the_rerun_writes_it(
    rng, minari_root, monkeypatch
):
    """Ctrl-C during `pcpg export minari` left a half-written dataset that Minari loaded with 0
    episodes, and the rerun that the interrupt message asked for refused: "already exists"."""
    from pcpg_dist.domains.trajectories import minari_io

    a, b = pcpg_dataset(rng, "a"), pcpg_dataset(rng, "b", lengths=(3, 4))
    real, calls = minari_io._episode_buffers, []

    def interrupted(ds):  # Ctrl-C while the second environment's episodes are written
        calls.append(ds.env)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(ds)

    monkeypatch.setattr(minari_io, "_episode_buffers", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_minari({"a": a, "b": b}, minari_root, "pcpg/int-v0")
    assert list(minari_root.iterdir()) == []  # no dataset, no temporary
    monkeypatch.setattr(minari_io, "_episode_buffers", real)
    written = write_minari({"a": a, "b": b}, minari_root, "pcpg/int-v0")
    assert sorted(written) == ["pcpg/int/a-v0", "pcpg/int/b-v0"]
    assert minari.load_dataset("pcpg/int/b-v0").total_episodes == 2
    assert sorted(p.name for p in minari_root.iterdir()) == ["pcpg"]


def test_a_sigkilled_export_leaves_a_temporary_root_the_next_export_removes(
    rng, minari_root, tmp_path
):
    """SIGKILL skips the export's cleanup: its hidden .pcpg-minari-*.tmp root stayed in --out for
    good. The next export into the folder removes it; a live export's root and another machine's stay."""
    import signal
    import subprocess
    import sys
    import time

    from pcpg_dist.domains.trajectories import minari_io

    minari_root.mkdir(parents=True)
    script = (
        "import time, numpy as np, sys\n"
        "sys.path.insert(0, 'tests/domains')\n"
        "from test_minari import pcpg_dataset\n"
        "from pcpg_dist.domains.trajectories import minari_io\n"
        "real = minari_io._episode_buffers\n"
        "def slow(ds):\n"
        "    time.sleep(600)\n"
        "minari_io._episode_buffers = slow\n"
        f"minari_io.write_minari({{'a': pcpg_dataset(np.random.default_rng(0), 'a')}}, {str(minari_root)!r}, 'pcpg/k-v0')\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=Path(__file__).parents[2])
    deadline = time.monotonic() + 120
    while not list(minari_root.glob(".pcpg-minari-*.tmp")) and time.monotonic() < deadline:
        time.sleep(0.2)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    (stale,) = minari_root.glob(".pcpg-minari-*.tmp")
    assert stale.name.startswith(f"{minari_io._build_prefix()}{proc.pid}-")
    live = minari_root / f"{minari_io._build_prefix()}{os.getpid()}-x.tmp"  # this process: alive
    other = minari_root / f".pcpg-minari-another-host-{proc.pid}-x.tmp"
    live.mkdir()
    other.mkdir()
    (written,) = write_minari({"b": pcpg_dataset(rng, "b")}, minari_root, "pcpg/k-v0")
    assert not stale.exists() and live.is_dir() and other.is_dir()
    assert minari.load_dataset(written).total_episodes == 5
