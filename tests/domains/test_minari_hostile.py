"""Hostile Minari folders: a Minari dataset read as `minari:ID` and the folder `pcpg export minari`
writes into are checked like every other input (pcpg_dist/common/inputs.py); each refusal is one
line naming the file or key, never a silent drop, a traceback or a write outside the folder."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from pcpg_dist.cli import main
from pcpg_dist.common.errors import DataError
from pcpg_dist.dataset import Dataset, write_datasets
from pcpg_dist.domains.trajectories.minari_io import write_minari
from pcpg_dist.domains.trajectories.minari_read import read_minari

ID = "pcpg/h-v0"
N_EPISODES = 6


@pytest.fixture(autouse=True)
def minari_root(tmp_path, monkeypatch):
    """Every test reads and writes Minari datasets under tmp_path, never ~/.minari."""
    root = tmp_path / "minari"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    return root


def small_dataset(n: int = N_EPISODES, steps: int = 3) -> Dataset:
    rng = np.random.default_rng(0)
    trajs = [
        {
            "states": rng.normal(size=(steps + 1, 2)),
            "actions": rng.integers(0, 3, steps),
            "valid": np.ones((steps + 1, 3), bool),
            "rewards": rng.normal(size=steps),
        }
        for _ in range(n)
    ]
    return Dataset.from_trajectories(
        "trajectories", "lvl", 3, trajs, styles=np.arange(n) % 2, success=np.ones(n, bool)
    )


@pytest.fixture
def data(minari_root) -> Path:
    """A real Minari dataset of 6 episodes (written by pcpg's export, read back by Minari): its
    ``data`` folder."""
    write_minari({"lvl": small_dataset()}, minari_root, ID)
    return minari_root / ID / "data"


def episode_file(data: Path, i: int) -> Path:
    (f,) = (p for p in (data / str(i)).iterdir() if p.name != "metadata.json")
    return f


def edit_metadata(data: Path, **changes) -> None:
    meta = json.loads((data / "metadata.json").read_text())
    meta.update(changes)
    for key, value in changes.items():
        if value is None:
            del meta[key]
    (data / "metadata.json").write_text(json.dumps(meta))


def refused(*needles: str) -> str:
    """The one-line DataError read_minari raises; every needle is in it."""
    with pytest.raises(DataError) as e:
        read_minari(ID)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"minari:{ID}: "), msg
    for needle in needles:
        assert needle in msg, (needle, msg)
    return msg


# --------------------------------------------------------------------------- pcpg export minari
def test_export_refuses_a_link_in_out_that_leads_outside_and_writes_nothing(tmp_path, capsys):
    """`DIR/pcpg -> elsewhere`: the export wrote the dataset into elsewhere, exit 0."""
    source = tmp_path / "mydata"
    write_datasets(source, [small_dataset()], {"source": "test"})
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (out / "pcpg").symlink_to(elsewhere)
    argv = ["export", "minari", str(source), "--out", str(out), "--dataset-id", "pcpg/x-v0"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("pcpg: error: "), err
    assert f"{out / 'pcpg'}: a link to {elsewhere}, outside {out}" in err, err
    assert list(elsewhere.iterdir()) == []  # nothing written outside
    assert [p.name for p in out.iterdir()] == ["pcpg"]  # and no half dataset or temporary root

    # a link that stays inside --out is followed: the dataset lands inside, and reads back
    (out / "pcpg").unlink()
    (out / "real").mkdir()
    (out / "pcpg").symlink_to(out / "real")
    assert main(argv) == 0
    capsys.readouterr()
    assert (out / "real" / "x-v0" / "data" / "metadata.json").is_file()
    assert list(elsewhere.iterdir()) == []


def test_export_refuses_a_dangling_link_where_the_dataset_goes(tmp_path, minari_root):
    minari_root.mkdir()
    (minari_root / "pcpg").mkdir()
    (minari_root / "pcpg" / "x-v0").symlink_to(tmp_path / "nowhere")
    with pytest.raises(DataError, match="outside"):
        write_minari({"lvl": small_dataset()}, minari_root, "pcpg/x-v0")
    assert not (tmp_path / "nowhere").exists()
    assert sorted(p.name for p in minari_root.iterdir()) == ["pcpg"]


# --------------------------------------------------------------------------- minari:ID, episodes
def test_an_episode_file_linked_to_dev_zero_is_one_line_in_pcpg_generate(
    tmp_path, data, capsys, monkeypatch
):
    """`data/3/part-0.arrow -> /dev/zero`: `pcpg generate` dropped that episode (5 of 6), exit 0."""
    from pcpg_dist.orchestration import ray_pool

    monkeypatch.setattr(ray_pool, "init_ray", lambda address: None)  # seconds, and no part of this
    f = episode_file(data, 3)
    f.unlink()
    f.symlink_to("/dev/zero")
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "name": "hostile",
                "domain": "trajectories",
                "seeds": [0],
                "trajectories": {"path": f"minari:{ID}", "score": "return"},
            }
        )
    )
    out = tmp_path / "out"
    assert main(["generate", str(cfg), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("pcpg: error: "), err
    assert f"{f}: a link to /dev/zero, outside {data / '3'}" in err, err
    assert not any(out.rglob("manifest.json")) if out.exists() else True


@pytest.mark.parametrize(
    "plant, needles",
    [
        ("missing", ["unreadable episode data (no such file", "/data/3", "'total_episodes' is 6"]),
        ("no data file", ["/data/3: no data file", "one per episode"]),
        ("two data files", ["/data/3: 2 data files", "one per episode"]),
        ("a subfolder", ["/data/3/sub: a folder inside an episode folder"]),
        ("empty", ["part-0.arrow: not an Arrow IPC file", "it starts b''"]),
        ("garbage", ["part-0.arrow: not an Arrow IPC file", "it starts b'garbag'"]),
        ("fifo", ["part-0.arrow: a FIFO, not a regular file"]),
        ("link out", ["/data/3: a link to", "outside"]),
        ("extra episode", ["'total_episodes' is 6", "7 episode folders", "/data/6"]),
    ],
)
def test_every_episode_is_checked_and_none_is_dropped(data, tmp_path, plant, needles):
    f = episode_file(data, 3)
    if plant == "missing":
        shutil.rmtree(data / "3")
    elif plant == "no data file":
        f.unlink()
    elif plant == "two data files":
        shutil.copy(episode_file(data, 2), data / "3" / "part-1.arrow")
    elif plant == "a subfolder":
        (data / "3" / "sub").mkdir()
    elif plant == "empty":
        f.write_bytes(b"")
    elif plant == "garbage":
        f.write_bytes(b"garbage" * 100)
    elif plant == "fifo":
        f.unlink()
        os.mkfifo(f)
    elif plant == "link out":
        shutil.move(data / "3", tmp_path / "ep3")
        (data / "3").symlink_to(tmp_path / "ep3")
    elif plant == "extra episode":
        shutil.copytree(data / "5", data / "6")
    refused(*needles)


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads a file whatever its mode")
def test_an_unreadable_episode_file_is_one_line(data):
    f = episode_file(data, 3)
    f.chmod(0)
    try:
        refused(f"{f}: unreadable (Permission denied)")
    finally:
        f.chmod(0o644)


def test_episode_files_larger_than_half_the_memory_are_refused(data, monkeypatch):
    import pcpg_dist.common.memory as memory

    largest = max(episode_file(data, i).stat().st_size for i in range(N_EPISODES))
    monkeypatch.setattr(memory, "machine_memory", lambda: 2 * largest)
    refused("the episode files under", "more than half of this machine's")


# --------------------------------------------------------------------------- minari:ID, metadata
def test_a_huge_total_episodes_is_refused_before_anything_is_allocated(data):
    """total_episodes 10**12: Minari's np.arange tried to allocate 7.28 TiB (34-line traceback)."""
    edit_metadata(data, total_episodes=10**12)
    start = time.monotonic()
    refused("'total_episodes' is 1,000,000,000,000", "6 episode folders are present")
    assert time.monotonic() - start < 10


def test_metadata_nested_100000_levels_is_one_line(data):
    """A metadata.json nested 100,000 levels deep was a RecursionError traceback."""
    meta = json.loads((data / "metadata.json").read_text())
    text = json.dumps(meta)[:-1] + ', "deep": ' + "[" * 100_000 + "]" * 100_000 + "}"
    (data / "metadata.json").write_text(text)
    refused(str(data / "metadata.json"), "JSON nested more than 64 levels deep")

    # a space (JSON text inside metadata.json) nested too deep: the same line, naming the key
    meta["observation_space"] = "[" * 100_000 + "]" * 100_000
    (data / "metadata.json").write_text(json.dumps(meta))
    refused("'observation_space'", "JSON nested more than 64 levels deep")


def test_a_metadata_file_over_the_size_limit_is_refused_unread(data):
    edit_metadata(data, description="x" * (17 << 20))
    refused(str(data / "metadata.json"), "over the limit of 16,777,216 bytes")


def test_metadata_json_that_is_a_link_out_or_a_fifo_is_one_line(data, tmp_path):
    meta = data / "metadata.json"
    shutil.move(meta, tmp_path / "meta.json")
    meta.symlink_to(tmp_path / "meta.json")
    refused(f"{meta}: a link to {tmp_path / 'meta.json'}, outside {data}")
    meta.unlink()
    os.mkfifo(meta)
    refused(f"{meta}: a FIFO, not a regular file")


@pytest.mark.parametrize(
    "changes, needles",
    [
        ({"total_episodes": -1}, ["'total_episodes' is -1; expected a whole number >= 0"]),
        ({"total_episodes": "6"}, ["'total_episodes' is '6'; expected a whole number >= 0"]),
        (
            {"total_steps": 10**12},
            ["'total_steps' is 1,000,000,000,000", "the episode files hold 6 episodes of 18 steps"],
        ),
        ({"data_format": "hdf5"}, ["'data_format' is 'hdf5'", "'arrow' or 'parquet'"]),
        ({"data_format": []}, ["'data_format' is []", "'arrow' or 'parquet'"]),  # found by fuzzing
        ({"dataset_id": 5}, ["'dataset_id' is 5; expected a string"]),
        ({"minari_version": None}, ["'minari_version' is missing; expected a string"]),
        # without its spaces Minari would build the environment named in env_spec (import code)
        ({"observation_space": None}, ["'observation_space' is missing", "never builds"]),
        ({"env_spec": 7}, ["'env_spec' is 7; expected JSON text"]),
    ],
)
def test_tampered_metadata_keys_are_one_line(data, changes, needles):
    edit_metadata(data, **changes)
    refused("metadata.json", *needles)


def test_an_untampered_dataset_still_reads_whole(data):
    table, meta = read_minari(ID)
    assert meta["total_episodes"] == N_EPISODES and meta["total_steps"] == 3 * N_EPISODES
    assert len(set(table.column("trajectory").to_pylist())) == N_EPISODES


def test_json_nesting_limit_is_exact_and_needs_no_recursion():
    from pcpg_dist.common.inputs import JSON_DEPTH, json_text

    ok = "[" * JSON_DEPTH + "]" * JSON_DEPTH
    assert json_text(ok, "x") is not None
    for text in ("[" * (JSON_DEPTH + 1) + "]" * (JSON_DEPTH + 1), '{"a": ' * 900 + "1" + "}" * 900):
        with pytest.raises(DataError, match=f"x: JSON nested more than {JSON_DEPTH} levels deep"):
            json_text(text, "x")
    with pytest.raises(DataError, match=r"x: not valid JSON \("):
        json_text(b"\xff{", "x")


def streamed_settings(stream: str = "on"):
    from pcpg_dist.config import ExperimentConfig

    cfg = ExperimentConfig.model_validate(
        {
            "name": "h",
            "domain": "trajectories",
            "trajectories": {"path": f"minari:{ID}", "stream": stream},
        }
    )
    return cfg.trajectories


def test_a_streamed_read_checks_the_files_and_every_episode_as_a_whole_read_does(data):
    """`stream: on`: the driver checks the dataset's files as a whole read does before anything
    runs; each block task checks its own episodes (one line naming the episode)."""
    from pcpg_dist.domains.trajectories.minari_stream import minari_stream_source, read_episodes

    source = minari_stream_source(streamed_settings(), "h")
    assert source.steps == 6 * 4 and source.states == ("s0", "s1") and source.n_actions == 3
    assert minari_stream_source(streamed_settings("auto"), "h") is None  # small: loaded whole
    columns = ["trajectory", "action", "s0", "s1", "reward", "style"]
    (table,) = [t for part in source.parts for t in read_episodes(part, columns)]
    whole, _ = read_minari(ID)
    for c in columns:  # a part's rows are the whole read's rows
        np.testing.assert_array_equal(table.column(c).to_numpy(), whole.column(c).to_numpy())

    meta = json.loads((data / "metadata.json").read_text())
    edit_metadata(data, action_space=meta["action_space"].replace('"n": 3', '"n": 2'))
    source = minari_stream_source(streamed_settings(), "h")
    with pytest.raises(DataError) as e:
        [t for part in source.parts for t in read_episodes(part, columns)]
    with pytest.raises(DataError) as whole_error:
        read_minari(ID)
    msg = str(e.value)  # the same line as the whole read's (here, episode 0's masks)
    assert "\n" not in msg and msg.startswith(f"minari:{ID}, episode 0: "), msg
    assert msg == str(whole_error.value)

    episode_file(data, 3).write_bytes(b"garbage" * 100)  # refused before any task runs
    with pytest.raises(DataError, match="part-0.arrow: not an Arrow IPC file"):
        minari_stream_source(streamed_settings(), "h")
