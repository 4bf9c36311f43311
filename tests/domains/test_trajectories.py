"""The built-in `trajectories` domain: a user's own Parquet logs through the whole pipeline.

Bad files fail with one line naming file, column and row (exit 2, nothing written); 1000 actions
work; clear styles are clustered close to what a supervised classifier reaches and PCPG beats No
Clustering; the trained agents are rolled out in the Gymnasium env the logs came from.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml

from pcpg_dist.cli import main
from pcpg_dist.common.errors import ConfigError, DataError
from pcpg_dist.config import load_config
from pcpg_dist.domains.trajectories.example_logs import frozenlake_logs
from pcpg_dist.domains.trajectories.table import datasets_from_table
from pcpg_dist.domains.trajectories.table_files import read_step_table
from pcpg_dist.pipeline import run_unit


def write_config(tmp_path: Path, logs: str | Path, **over) -> Path:
    raw = {
        "name": "own_logs",
        "domain": "trajectories",
        "seeds": [0],
        "trajectories": {"path": str(logs), "score": "return"},
        "clustering": {"k": 4, "method": "visits_kmeans"},
        "ranking": {"ps": [1.0, 0.5]},
        "bc": {"epochs": 300, "hidden_size": 16},
        "evaluation": {"corruption_levels": [], "figures": False, "rollouts_per_policy": 20},
    }
    for key, value in over.items():
        section, _, name = key.partition("__")
        if name:
            raw.setdefault(section, {})[name] = value
        else:
            raw[section] = value
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def tiny_table(
    n_traj: int = 6, steps: int = 4, d: int = 2, n_actions: int = 3, seed: int = 0
) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n_traj):
        for t in range(steps + 1):
            rows.append(
                {
                    "trajectory": i,
                    "t": t,
                    **{f"s{j}": float(rng.normal()) for j in range(d)},
                    "action": int(rng.integers(n_actions)) if t < steps else -1,
                    "reward": float(rng.random()) if t < steps else 0.0,
                }
            )
    return pd.DataFrame(rows)


def load(df: pd.DataFrame, tmp_path: Path, name: str = "logs.parquet", **kw):
    path = tmp_path / name
    df.to_parquet(path, index=False)
    return datasets_from_table(read_step_table(path), **kw)


# ------------------------------------------------------------------ the contract
def test_round_trip_of_a_small_table(tmp_path) -> None:
    df = tiny_table()
    (ds,) = load(df, tmp_path).values()
    assert (ds.n_trajectories, ds.n_rows, ds.n_actions, ds.state_dim) == (6, 30, 3, 2)
    assert ds.env == "logs" and ds.feature_names == ("s0", "s1")
    np.testing.assert_allclose(ds.states[:, 0], df.s0.to_numpy(np.float32))
    np.testing.assert_array_equal(ds.actions, df.action)
    assert ds.valid.all() and (ds.styles == -1).all()
    np.testing.assert_allclose(ds.returns, df.groupby("trajectory").reward.sum())


def test_rows_may_come_in_any_order_and_ids_may_be_strings(tmp_path) -> None:
    df = tiny_table()
    shuffled = df.sample(frac=1.0, random_state=1).sort_values(["t"], kind="stable")
    shuffled["trajectory"] = "run-" + shuffled["trajectory"].astype(str)
    (a,) = load(df, tmp_path, "a.parquet").values()
    (b,) = load(shuffled, tmp_path, "b.parquet").values()
    np.testing.assert_array_equal(a.states, b.states)
    np.testing.assert_array_equal(a.actions, b.actions)


def test_an_open_last_step_gets_a_closing_row(tmp_path) -> None:
    df = tiny_table(n_traj=2, steps=3)
    df = df[df.action >= 0]  # logs that record an action on every row
    (ds,) = load(df, tmp_path).values()
    assert ds.lengths.tolist() == [4, 4]
    last = ds.offsets[1:] - 1
    assert (ds.actions[last] == -1).all()
    np.testing.assert_array_equal(ds.states[last], ds.states[last - 1])  # the repeated final state


def test_env_column_makes_units_and_a_folder_of_files_is_one_table(tmp_path) -> None:
    a, b = tiny_table(seed=1), tiny_table(seed=2)
    a["env"], b["env"] = "level one", "level/two"
    b["trajectory"] += 100
    folder = tmp_path / "logs"
    folder.mkdir()
    a.to_parquet(folder / "part-0.parquet", index=False)
    b.to_parquet(folder / "part-1.parquet", index=False)
    out = datasets_from_table(read_step_table(folder))
    assert sorted(out) == ["level_one", "level_two"]  # names made safe for folders
    assert all(ds.n_trajectories == 6 for ds in out.values())


def test_a_thousand_actions_with_valid_lists(tmp_path) -> None:
    rng = np.random.default_rng(0)
    n_actions, rows = 1000, []
    for i in range(40):
        style = i % 2
        for t in range(6):
            valid = rng.random(n_actions) < 0.3
            action = 100 * style + t if t < 5 else -1
            if action >= 0:
                valid[action] = True
            rows.append(
                {
                    "trajectory": i,
                    "t": t,
                    "s0": float(t),
                    "s1": float(style),
                    "action": action,
                    "valid": valid.tolist(),
                    "style": style,
                }
            )
    (ds,) = load(pd.DataFrame(rows), tmp_path).values()
    assert ds.n_actions == 1000 and ds.valid.shape == (ds.n_rows, 1000)
    cfg = load_config(
        write_config(
            tmp_path,
            tmp_path / "logs.parquet",
            clustering={"k": 2, "method": "summary_kmeans"},
            bc={"epochs": 400, "hidden_size": 16, "lr": 0.05},
        )
    )
    (unit,) = cfg.domain_object.units(cfg, {"logs": ds})
    m = run_unit(unit, cfg).metrics
    assert m["clustering/accuracy"] == 1.0
    # the action is a function of (t, style): far above the ~1/300 of guessing among valid actions
    assert m["pcpg/accuracy/p1"] > 0.9 > 0.05 > m["random/accuracy"]


BAD = {
    "missing column": (lambda df: df.drop(columns="t"), "missing column 't'"),
    "fractional action": (
        lambda df: df.assign(action=df.action.astype(float).where(df.index != 3, 1.5)),
        "column 'action', row 3: 1.5 is not an integer",
    ),
    "action out of range": (lambda df: df.assign(action=df.action.where(df.index != 2, 7)), None),
    "negative mid action": (
        lambda df: df.assign(action=df.action.where(df.index != 1, -5)),
        "column 'action', row 1: action -5 is not allowed",
    ),
    "t repeated": (
        lambda df: df.assign(t=df.t.where(df.index != 2, 0)),
        "column 't', rows 0 and 2: trajectory 0 has two rows with t = 0; each step of a trajectory "
        "needs its own t",
    ),
    "NaN state": (
        lambda df: df.assign(s1=df.s1.where(df.index != 4, np.nan)),
        "column 's1', row 4: is empty",
    ),
    "infinite state": (
        lambda df: df.assign(s1=df.s1.where(df.index != 4, np.inf)),
        "column 's1', row 4: inf is not a finite 32-bit float",
    ),
    "style changes": (
        lambda df: df.assign(style=np.where(df.index == 2, 1, 0)),
        "column 'style', row 2: changes within a trajectory",
    ),
    "state gap": (lambda df: df.rename(columns={"s1": "s2"}), "s1 is missing"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_files_fail_in_one_line_naming_file_column_and_row(case, tmp_path) -> None:
    make, needle = BAD[case]
    n_actions = 3 if case == "action out of range" else None
    with pytest.raises(DataError) as e:
        load(make(tiny_table()), tmp_path, "bad.parquet", n_actions=n_actions)
    msg = str(e.value)
    assert len(msg.splitlines()) == 1 and msg.startswith(str(tmp_path / "bad.parquet"))
    assert (needle or "column 'action', row 2: action 7 is outside 0..2") in msg


def test_cli_on_a_bad_file_exits_2_and_writes_nothing(tmp_path, capsys) -> None:
    path = tmp_path / "bad.parquet"
    BAD["negative mid action"][0](tiny_table()).to_parquet(path, index=False)
    code = main(
        [
            "run",
            str(write_config(tmp_path, path)),
            "--no-tracking",
            "--quiet",
            "--workdir",
            str(tmp_path / "runs"),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"{path}: column 'action', row 1: action -5 is not allowed" in err
    assert not (tmp_path / "runs").exists()  # nothing written


def arrow_table(**columns) -> pa.Table:
    """``tiny_table()`` as an Arrow table, with columns replaced or added (a column of None drops it)."""
    table = pa.Table.from_pandas(tiny_table(), preserve_index=False)
    for name, values in columns.items():
        i = table.schema.get_field_index(name)
        table = table.remove_column(i) if i >= 0 else table
        if values is not None:
            table = table.append_column(
                name, values if isinstance(values, pa.Array) else pa.array(values)
            )
    return table


def load_arrow(table: pa.Table, tmp_path: Path, name: str):
    pq.write_table(table, tmp_path / name)
    return datasets_from_table(read_step_table(tmp_path / name))


ROWS = 30  # tiny_table(): 6 trajectories of 5 rows
BAD_TYPES = {  # what pyarrow cannot cast (was a traceback), and values that change on the cast
    "env of lists": (
        {"env": [[1]] * ROWS},
        "column 'env' has type list<element: int64>; expected strings or integers",
    ),
    "env of structs": (
        {"env": [{"a": 1}] * ROWS},
        "column 'env' has type struct<a: int64>; expected strings",
    ),
    "trajectory of lists": (
        {"trajectory": [[i // 5] for i in range(ROWS)]},
        "column 'trajectory' has type list<element: int64>; expected integers or strings",
    ),
    "env not UTF-8": (
        {"env": pa.array([b"\xff"] * ROWS)},
        "column 'env', row 0: b'\\xff' is not UTF-8 text",
    ),
    "valid null in row 0": (
        {"valid": pa.array([None] + [[True] * 3] * (ROWS - 1), pa.list_(pa.bool_()))},
        "column 'valid', row 0: is empty (null); every row needs a list of booleans",
    ),
    "s01 for s1": (
        {"s01": np.zeros(ROWS), "s1": None},
        "column 's01' has a leading zero; state columns are "
        "named s0, s1, ... s{d-1} without leading zeros (rename it s1)",
    ),
    "uint64 action": (
        {"action": pa.array(np.where(np.arange(ROWS) == 4, 2**64 - 1, 0).astype(np.uint64))},
        "column 'action', row 4: 18446744073709551615 does not fit a 64-bit signed integer",
    ),
    "uint64 t": (
        {"t": pa.array(np.where(np.arange(ROWS) == 1, 2**64 - 1, 0).astype(np.uint64))},
        "column 't', row 1: 18446744073709551615 does not fit a 64-bit signed integer",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_TYPES))
def test_column_types_and_uint64_values_are_one_line_naming_the_column(
    case, tmp_path, capsys
) -> None:
    columns, needle = BAD_TYPES[case]
    path = tmp_path / "bad.parquet"
    pq.write_table(arrow_table(**columns), path)
    with pytest.raises(DataError) as e:
        datasets_from_table(read_step_table(path))
    assert str(e.value).startswith(f"{path}: {needle}"), str(e.value)
    code = main(
        ["generate", str(write_config(tmp_path, path)), "--out", str(tmp_path / "out"), "--quiet"]
    )
    err = capsys.readouterr().err.strip()
    assert (
        code == 2
        and err.startswith("pcpg: error: ")
        and len(err.splitlines()) == 1
        and needle in err
    ), err
    assert not (tmp_path / "out").exists()


def test_trajectory_ids_that_are_bytes_need_not_be_utf8(tmp_path) -> None:
    """Ids are only compared, so bytes are ids as they are (was an ArrowInvalid on a cast to text)."""
    ids = pa.array([b"\xff" + bytes([i // 5]) for i in range(ROWS)])
    (as_bytes,) = load_arrow(arrow_table(trajectory=ids), tmp_path, "bytes.parquet").values()
    (as_ints,) = load(tiny_table(), tmp_path).values()
    np.testing.assert_array_equal(as_bytes.states, as_ints.states)
    np.testing.assert_array_equal(as_bytes.actions, as_ints.actions)


def test_a_folder_names_the_file_that_differs_and_a_files_own_row(tmp_path, capsys) -> None:
    folder = tmp_path / "logs"
    folder.mkdir()
    first, second = tiny_table(seed=1), tiny_table(seed=2)
    second["trajectory"] += 100
    first.to_parquet(folder / "a.parquet", index=False)
    for edit, needle in (
        (
            lambda df: df.drop(columns="reward"),
            "b.parquet: has no column 'reward', which a.parquet has",
        ),
        (lambda df: df.assign(s2=0.0), "b.parquet: column 's2' is not in a.parquet"),
        (
            lambda df: df.assign(s1="x"),
            "b.parquet: column 's1' has type large_string, but double in a.parquet",
        ),
        (
            lambda df: df.assign(
                action=df.action.where(df.index != 3, -5)
            ),  # row 33 of the whole table
            "b.parquet: column 'action', row 3: action -5 is not allowed",
        ),
    ):
        edit(second).to_parquet(folder / "b.parquet", index=False)
        with pytest.raises(DataError) as e:
            datasets_from_table(read_step_table(folder))
        assert str(e.value).startswith(f"{folder / needle}"), str(e.value)
    code = main(
        ["generate", str(write_config(tmp_path, folder)), "--out", str(tmp_path / "out"), "--quiet"]
    )
    err = capsys.readouterr().err.strip()
    assert (
        code == 2
        and err
        == f"pcpg: error: {folder / 'b.parquet'}: column 'action', row 3: action -5 is not "
        "allowed (0..n-1; -1 only on a trajectory's last row)"
    ), err
    assert not (tmp_path / "out").exists()


def test_trajectory_ids_restarting_in_each_file_of_a_folder_name_both_files(tmp_path) -> None:
    """Daily files whose ids restart at 0 were reported as `t = 0 does not increase within trajectory 0`."""
    folder = tmp_path / "logs"
    folder.mkdir()
    tiny_table(seed=1).to_parquet(folder / "day1.parquet", index=False)
    tiny_table(seed=2).to_parquet(folder / "day2.parquet", index=False)
    with pytest.raises(DataError) as e:
        datasets_from_table(read_step_table(folder))
    assert str(e.value) == (
        f"{folder / 'day2.parquet'}: trajectory 0 appears both in {folder / 'day1.parquet'} and "
        f"in this file (its t restarts at 0 here after 4 there); trajectory ids must be unique "
        f"across a folder's files: give each file's trajectories distinct ids (e.g. prefixed by "
        f"the file's name)"
    )
    # ids restarting with t ranges that do not overlap (day1's trajectory 0 at t 10.., day2's at
    # t 0..): merged into one trajectory since rows were ordered by t; a restart all the same
    day1, day2 = tiny_table(n_traj=1, seed=1), tiny_table(n_traj=1, seed=2)
    day1["t"] += 10
    day1.to_parquet(folder / "day1.parquet", index=False)
    day2.to_parquet(folder / "day2.parquet", index=False)
    with pytest.raises(DataError) as e:
        datasets_from_table(read_step_table(folder))
    assert str(e.value).startswith(
        f"{folder / 'day2.parquet'}: trajectory 0 appears both in "
        f"{folder / 'day1.parquet'} and in this file (its t restarts at 0 here after "
        f"{day1.t.max()} there)"
    )
    # a trajectory that goes on in the next file (t still increasing) is one trajectory, as before
    whole = tiny_table(n_traj=2)
    whole.iloc[:3].to_parquet(folder / "day1.parquet", index=False)
    whole.iloc[3:].to_parquet(folder / "day2.parquet", index=False)
    (ds,) = datasets_from_table(read_step_table(folder)).values()
    assert ds.n_trajectories == 2 and ds.n_rows == len(whole)


def test_a_path_that_is_not_a_regular_file_or_folder_says_so(tmp_path) -> None:
    import os

    fifo = tmp_path / "logs.parquet"
    os.mkfifo(fifo)
    for path in (fifo, Path("/dev/zero")):
        with pytest.raises(DataError) as e:
            read_step_table(path)
        assert str(e.value) == (
            f"{path}: not a regular file or folder; trajectories.path names a Parquet file "
            f"or a folder of them"
        )
    with pytest.raises(DataError, match="no such file or folder"):
        read_step_table(tmp_path / "none.parquet")


def test_a_table_of_single_row_trajectories_says_no_trajectory_has_a_step(tmp_path) -> None:
    """It said `0 actions; pcpg handles 1..1000000`."""
    single = tiny_table(n_traj=5, steps=0)
    with pytest.raises(DataError) as e:
        load(single, tmp_path)
    assert str(e.value) == (
        f"{tmp_path / 'logs.parquet'}: no trajectory has a step: each of the 5 trajectories is a "
        f"single row (action -1, its closing state); a trajectory needs rows with actions 0..n-1 "
        f"before its last"
    )


def test_a_folder_refuses_a_link_leaving_it_and_reads_upper_case_parquet_names(tmp_path) -> None:
    folder, outside = tmp_path / "logs", tmp_path / "elsewhere"
    folder.mkdir()
    outside.mkdir()
    tiny_table(seed=1).to_parquet(folder / "a.parquet", index=False)
    second = tiny_table(seed=2)
    second["trajectory"] += 100
    second.to_parquet(outside / "secret.parquet", index=False)
    (folder / "b.parquet").symlink_to(outside / "secret.parquet")
    with pytest.raises(DataError) as e:  # it was read as part of the folder
        read_step_table(folder)
    assert str(e.value).startswith(
        f"step table {folder / 'b.parquet'}: a link to {outside / 'secret.parquet'}, outside "
        f"{folder}; refusing to read it"
    )
    (folder / "b.parquet").unlink()
    (folder / "inside.parquet").symlink_to(folder / "a.parquet")  # a link within: read
    assert read_step_table(folder) is not None
    (folder / "inside.parquet").unlink()
    os.mkfifo(folder / "c.parquet")  # was skipped without a word
    with pytest.raises(DataError) as e:
        read_step_table(folder)
    assert str(e.value).startswith(f"step table {folder / 'c.parquet'}: a FIFO, not a regular file")
    (folder / "c.parquet").unlink()
    second.to_parquet(folder / "B.PARQUET", index=False)  # was skipped without a word
    (ds,) = datasets_from_table(read_step_table(folder)).values()
    assert ds.n_trajectories == 12


def test_action_outside_its_valid_mask(tmp_path) -> None:
    df = tiny_table()
    df["valid"] = [[True, True, True]] * len(df)
    df.at[5, "valid"] = [a != df.action[5] for a in range(3)]
    with pytest.raises(
        DataError, match=r"column 'action', row 5: action \d is not in the row's valid mask"
    ):
        load(df, tmp_path)
    df.at[5, "valid"] = [True, True]
    with pytest.raises(DataError, match=r"column 'valid', row 5: 2 entries, expected 3"):
        load(df, tmp_path)


def test_score_choices_and_an_unknown_column(tmp_path) -> None:
    df = tiny_table()
    df["skill"] = df.trajectory * 10.0
    path = tmp_path / "logs.parquet"
    df.to_parquet(path, index=False)
    for how, expected in (
        ("return", df.groupby("trajectory").reward.sum().to_numpy()),
        ("-length", -np.full(6, 5.0)),
        ("skill", np.arange(6) * 10.0),
    ):
        cfg = load_config(
            write_config(tmp_path, path, trajectories={"path": str(path), "score": how})
        )
        (ds,) = cfg.domain_object.generate(cfg, show_progress=False).values()
        np.testing.assert_allclose(cfg.domain_object.score(cfg)(ds), expected)
    cfg = load_config(
        write_config(tmp_path, path, trajectories={"path": str(path), "score": "skil"})
    )
    with pytest.raises(DataError, match="names column 'skil'.*skill"):
        cfg.domain_object.generate(cfg, show_progress=False)


# ------------------------------------------------------------------ the whole pipeline
def test_logs_without_styles_still_run(tmp_path) -> None:
    df = frozenlake_logs(per_style=25, seed=3).drop(columns="style")
    path = tmp_path / "lake.parquet"
    df.to_parquet(path, index=False)
    cfg = load_config(write_config(tmp_path, path, bc={"epochs": 150, "hidden_size": 8}))
    (unit,) = cfg.domain_object.units(cfg, cfg.domain_object.generate(cfg, show_progress=False))
    m = run_unit(unit, cfg).metrics
    assert "clustering/accuracy" not in m and "clustering/ceiling" not in m
    assert m["pcpg/accuracy/p1"] > m["random/accuracy"] + 0.2


def test_gymnasium_rollouts_report_each_agents_success_rate(tmp_path) -> None:
    """docs/bring-your-own-data.md "Gymnasium rollouts": per agent the mean return, the length and
    the success rate. On FrozenLake with `terminated_positive_reward` an episode succeeds exactly
    when it earns the goal's reward of 1, so each agent's success rate equals its mean return."""
    path = tmp_path / "lake.parquet"
    frozenlake_logs(per_style=25, seed=3).to_parquet(path, index=False)
    cfg = load_config(
        write_config(
            tmp_path,
            path,
            bc={"epochs": 150, "hidden_size": 8},
            trajectories={
                "path": str(path),
                "score": "return",
                "gymnasium_env": "FrozenLake-v1",
                "gymnasium_kwargs": {"map_name": "8x8", "is_slippery": False},
                "gymnasium_success": "terminated_positive_reward",
            },
            evaluation={
                "corruption_levels": [],
                "figures": False,
                "rollouts_per_policy": 5,
                "max_steps": 100,
            },
        )
    )
    (unit,) = cfg.domain_object.units(cfg, cfg.domain_object.generate(cfg, show_progress=False))
    m = run_unit(unit, cfg, out_dir=tmp_path / "eval").metrics
    agents = [f"{who}/p{p}" for who in ("k0", "k1", "k2", "k3", "nc") for p in ("1", "0.5")]
    for agent in agents:
        assert m[f"rollout/success/{agent}"] == pytest.approx(m[f"rollout/return/{agent}"]), agent
    assert (
        0 < np.mean([m[f"rollout/success/{a}"] for a in agents]) <= 1
    )  # some agents reach the goal
    table = pd.read_csv(tmp_path / "eval" / "rollout_success.csv")
    assert len(table) == len(agents)
    assert sorted(table["mean"]) == pytest.approx(sorted(m[f"rollout/success/{a}"] for a in agents))
    # each style's agent plays its own route: classified back to its own cluster by the clustering
    # model (what `pcpg classify` does) in most episodes; No Clustering has no cluster to keep
    kept = [m[f"rollout/style_kept/k{c}/p1"] for c in range(4)]
    assert all(0 <= x <= 1 for x in kept) and np.mean(kept) >= 0.75, kept
    assert m["rollout/style_kept/p1"] == pytest.approx(np.mean(kept))
    assert not any(key.startswith("rollout/style_kept/nc") for key in m)


@pytest.mark.slow
def test_own_logs_end_to_end_with_gymnasium_rollouts(ray_session, tmp_path) -> None:
    """Four clear styles on FrozenLake 8x8, never used to choose anything: clustering within 3
    points of the supervised ceiling, PCPG above No Clustering at p = 1, agents rolled out in the
    real Gymnasium env."""
    from pcpg_dist.api.run import run_experiment

    path = tmp_path / "lake.parquet"
    frozenlake_logs(per_style=150, seed=7).to_parquet(path, index=False)
    cfg = load_config(
        write_config(
            tmp_path,
            path,
            seeds=[0, 1],
            trajectories={
                "path": str(path),
                "score": "return",
                "gymnasium_env": "FrozenLake-v1",
                "gymnasium_kwargs": {"map_name": "8x8", "is_slippery": False},
                "gymnasium_success": "terminated_positive_reward",
            },
            evaluation={
                "corruption_levels": [0.0, 1.0],
                "figures": True,
                "rollouts_per_policy": 10,
                "max_steps": 100,
            },
        )
    )
    result = run_experiment(cfg, workdir=tmp_path / "runs", track=False, show_progress=False)
    m = result.metrics
    assert m["clustering/accuracy"] >= m["clustering/ceiling"] - 0.03
    assert m["pcpg/accuracy/p1"] > m["baseline/accuracy/p1"]
    # styles share their first steps (all start in one corner): 3 of 4 rows is what this data gives
    assert m["cross/diagonal_is_row_max"] >= 0.75
    print(
        {
            k: round(v, 3)
            for k, v in m.items()
            if k.split("/")[0] in ("clustering", "pcpg", "baseline", "cross")
            or k.startswith("rollout/return")
        }
    )
    # the agents walk the real lake: most PCPG agents at p = 1 reach the goal
    returns = [v for k, v in m.items() if k.startswith("rollout/return/k") and k.endswith("/p1")]
    assert len(returns) == 4 and np.mean(returns) > 0.5
    env_dir = result.out_dir / "summary" / "lake0"
    for name in (
        "cross_accuracy.csv",
        "accuracy.csv",
        "rollout_return.csv",
        "corruption_accuracy.csv",
    ):
        assert (env_dir / name).is_file(), name
    assert (
        json.loads((result.out_dir / "summary" / "metrics.json").read_text())["clustering/accuracy"]
        > 0.9
    )


def test_a_local_minari_dataset_runs_like_a_parquet_log(tmp_path, monkeypatch) -> None:
    """`path: minari:ID`: the same trajectories give the same datasets as the Parquet log."""
    from pcpg_dist.domains.trajectories.minari_io import write_minari

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    path = tmp_path / "lake.parquet"
    frozenlake_logs(per_style=20, seed=5).drop(columns="env").to_parquet(path, index=False)
    (from_parquet,) = datasets_from_table(read_step_table(path)).values()
    write_minari({"lake": from_parquet}, tmp_path / "minari", "pcpg/lake-v0")
    cfg = load_config(
        write_config(tmp_path, "minari:pcpg/lake-v0", bc={"epochs": 150, "hidden_size": 8})
    )
    (ds,) = cfg.domain_object.generate(cfg, show_progress=False).values()
    np.testing.assert_array_equal(ds.states, from_parquet.states)
    np.testing.assert_array_equal(ds.actions, from_parquet.actions)
    np.testing.assert_array_equal(ds.styles, from_parquet.styles)
    np.testing.assert_allclose(ds.returns, from_parquet.returns)
    (unit,) = cfg.domain_object.units(cfg, {ds.env: ds})
    m = run_unit(unit, cfg).metrics
    assert m["clustering/accuracy"] > 0.9 and m["pcpg/accuracy/p1"] > m["random/accuracy"] + 0.2


@pytest.mark.parametrize("dataset_id", ["/usr", "../../../usr", "/", "a/../b-v0", " "])
def test_a_minari_path_that_is_not_an_id_is_refused_at_load_before_any_folder_is_read(
    tmp_path, dataset_id
):
    """`minari:/usr` used to hash every file under /usr (43 s for 6 GB) before the id was checked."""
    with pytest.raises(ConfigError) as e:
        load_config(write_config(tmp_path, f"minari:{dataset_id}"))
    assert "is not a Minari dataset id" in str(e.value) and "\n" not in str(e.value)


def test_a_huge_action_number_is_refused_before_its_mask_is_built(tmp_path, monkeypatch) -> None:
    """One action 999999 in a 26 KB table made a (rows x 10^6) mask: 23.5 GB, then a silent kill."""
    import pcpg_dist.common.memory as stages

    monkeypatch.setattr(stages, "machine_memory", lambda: 8 << 30)  # the same answer on any machine
    df = tiny_table(n_traj=400)
    df.loc[0, "action"] = 999_999
    with pytest.raises(DataError) as e:
        load(df, tmp_path)
    msg = str(e.value)
    assert "2000 steps x 1000000 actions (the largest action + 1) needs about 16.8 GiB" in msg, msg
    assert "actions are numbered 0..n-1" in msg and "\n" not in msg
    with pytest.raises(DataError, match=r"x 1000000 actions \(trajectories.n_actions\)"):
        load(tiny_table(n_traj=400), tmp_path, n_actions=1_000_000)


@pytest.mark.parametrize(
    "column", ["s1\u0660", "s\u0661", "s\uff11"]
)  # Arabic-Indic, full-width digits
def test_a_state_column_with_non_ascii_digits_is_one_line(tmp_path, column) -> None:
    """'s1٠' was read as state 10 and failed in a KeyError traceback; 's١' was called a leading zero."""
    df = (
        tiny_table(d=11).rename(columns={"s10": column})
        if column == "s1\u0660"
        else tiny_table().assign(**{column: 1.0})
    )
    with pytest.raises(DataError) as e:
        load(df, tmp_path)
    assert f"column {column!r} names a state with non-ASCII digits" in str(e.value)


def test_an_env_named_like_a_summary_file_is_refused_before_clustering(tmp_path, capsys) -> None:
    """env 'metrics.json' ran every stage, then collided with summary/metrics.json (every rerun too)."""
    path = tmp_path / "logs.parquet"
    df = frozenlake_logs(per_style=10, seed=1)
    df["env"] = np.where(df.trajectory % 2 == 0, "metrics.json", "lake")
    df.to_parquet(path, index=False)
    code = main(
        [
            "run",
            str(write_config(tmp_path, path)),
            "--no-tracking",
            "--quiet",
            "--workdir",
            str(tmp_path / "runs"),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert "environment name 'metrics.json' is the name of a file or folder pcpg writes" in err
    run = tmp_path / "runs" / "own_logs"
    assert not (run / "cache" / "cluster").exists() and not (run / "summary").exists()


def test_style_margin_on_continuous_states_with_bag_auto_has_its_margins(tmp_path) -> None:
    """bag_auto falls back to policy_mix on continuous states, which has a likelihood: Step B's
    style margin works there (with lstm_dec, the fallback before, it was refused)."""
    from pcpg_dist.config import parse_config
    from pcpg_dist.domains import contract
    from pcpg_dist.stages.clustering import cluster
    from pcpg_dist.stages.ranking import check_margins_come

    path = tmp_path / "logs.parquet"
    tiny_table(n_traj=12, steps=5).to_parquet(path, index=False)
    raw = {
        "name": "own",
        "domain": "trajectories",
        "trajectories": {"path": str(path)},
        "clustering": {"k": 2, "method": "bag_auto", "policy_steps": 5, "em_iterations": 2},
        "ranking": {"style_margin": 1.0},
    }
    cfg = parse_config(raw, source="own")
    (ds,) = contract.generate(cfg, show_progress=False).values()
    check_margins_come(cfg, [ds])  # no error: the fallback has margins
    found = cluster(ds, cfg.clustering, 0)
    assert found.metrics["auto_fell_back"] == 1.0 and found.margins is not None


@pytest.mark.parametrize(
    "key, value, needle",
    [
        ("pcpg.feature_names", 5, "metadata 'pcpg.feature_names' is 5; expected a list of names"),
        ("pcpg.action_names", 5, "metadata 'pcpg.action_names' is 5; expected a list of names"),
        # Minari reads every episode the metadata counts when asked for its iterator (was 'cannot access')
        ("total_episodes", 100, "unreadable episode data (no such file"),
    ],
)
def test_tampered_minari_metadata_is_one_line(tmp_path, monkeypatch, key, value, needle) -> None:
    from pcpg_dist.domains.trajectories.minari_io import write_minari
    from pcpg_dist.domains.trajectories.minari_read import read_minari

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    path = tmp_path / "lake.parquet"
    frozenlake_logs(per_style=3, seed=5).drop(columns="env").to_parquet(path, index=False)
    (ds,) = datasets_from_table(read_step_table(path)).values()
    write_minari({"lake": ds}, tmp_path / "minari", "pcpg/lake-v0")
    meta_file = tmp_path / "minari" / "pcpg" / "lake-v0" / "data" / "metadata.json"
    meta = json.loads(meta_file.read_text())
    *parents, last = key.split(".")
    target = meta
    for name in parents:
        target = target[name]
    target[last] = value
    meta_file.write_text(json.dumps(meta))
    with pytest.raises(DataError) as e:
        read_minari("pcpg/lake-v0")
    assert needle in str(e.value) and "\n" not in str(e.value)


def test_logs_that_never_took_the_envs_last_action_are_told_to_set_n_actions(tmp_path) -> None:
    """Logs without action 3 on FrozenLake (4 actions): the message blamed a 'valid' column the
    logs did not have; it now says where the count came from and which key to set."""
    df = frozenlake_logs(per_style=10, seed=3)
    df = df[~df.trajectory.isin(df.trajectory[df.action == 3])]
    path = tmp_path / "lake.parquet"
    df.to_parquet(path, index=False)
    lake = {
        "path": str(path),
        "score": "return",
        "gymnasium_env": "FrozenLake-v1",
        "gymnasium_kwargs": {"map_name": "8x8", "is_slippery": False},
    }
    cfg = load_config(write_config(tmp_path, path, trajectories=lake))
    with pytest.raises(ConfigError) as e:
        cfg.domain_object.units(cfg, cfg.domain_object.generate(cfg, show_progress=False))
    msg = str(e.value)
    assert (
        "but the logs have 3 (trajectories.n_actions, else the width of a 'valid' column, else the largest "
        "action + 1); if the players never took action 3, set trajectories.n_actions: 4" in msg
    ), msg
    cfg = load_config(write_config(tmp_path, path, trajectories={**lake, "n_actions": 4}))
    (unit,) = cfg.domain_object.units(cfg, cfg.domain_object.generate(cfg, show_progress=False))
    assert unit.dataset.n_actions == 4


# ------------------------------------------------------------------ rollouts that fit the logs
def balance(states: np.ndarray, valid: np.ndarray, rng) -> np.ndarray:
    """CartPole's angle PD controller (benchmarks/zoo/cartpole's first style): it keeps the pole
    up for the env's whole 500-step limit."""
    return (states[:, 2] + 0.3 * states[:, 3] > 0).astype(np.int64)


def push_left(states: np.ndarray, valid: np.ndarray, rng) -> np.ndarray:
    """Always push left: the pole falls (the env terminates) within a few dozen steps."""
    return np.zeros(len(states), np.int64)


def cartpole_logs(path: Path, n: int = 4) -> Path:
    """``n`` CartPole-v1 episodes of :func:`balance` as a step table: each runs the env's 500 steps."""
    import gymnasium

    rows = []
    env = gymnasium.make("CartPole-v1")
    for i in range(n):
        obs, _ = env.reset(seed=i)
        done, t = False, 0
        while True:
            a = -1 if done else int(balance(obs[None], np.ones((1, 2), bool), None)[0])
            rows.append({"trajectory": i, "t": t, **{f"s{j}": float(obs[j]) for j in range(4)}})
            rows[-1]["action"] = a
            if done:
                break
            obs, reward, terminated, truncated, _ = env.step(a)
            rows[-1]["reward"] = float(reward)
            done, t = terminated or truncated, t + 1
    env.close()
    pd.DataFrame(rows).fillna({"reward": 0.0}).to_parquet(path, index=False)
    return path


@pytest.fixture(scope="module")
def cartpole_parquet(tmp_path_factory) -> Path:
    return cartpole_logs(tmp_path_factory.mktemp("cartpole") / "cartpole.parquet")


@pytest.fixture
def pcpg_log(caplog, monkeypatch):
    """pcpg's log records, also after the CLI made the package's logger stop propagating."""
    import logging

    monkeypatch.setattr(logging.getLogger("pcpg_dist"), "propagate", True)
    caplog.set_level(logging.INFO, logger="pcpg_dist")
    return caplog


def cartpole_rollout(tmp_path, logs: Path, policy, n: int = 3, **over):
    """The trajectories domain's units and rollout hook for CartPole logs, as a run makes them."""
    from pcpg_dist.domains import contract

    cfg = load_config(
        write_config(
            tmp_path,
            logs,
            trajectories={"path": str(logs), "gymnasium_env": "CartPole-v1", **over},
        )
    )
    units = contract.units(cfg, contract.generate(cfg, show_progress=False))
    hooks = contract.hooks(cfg, units[0].name)
    return hooks.rollout(policy, n, np.random.default_rng(0)), cfg


def test_rollouts_reach_the_logged_length_when_max_steps_is_unset(
    tmp_path, cartpole_parquet, pcpg_log
) -> None:
    logged = pd.read_parquet(cartpole_parquet)
    assert logged.groupby("trajectory").size().max() - 1 == 500
    ds, cfg = cartpole_rollout(
        tmp_path, cartpole_parquet, balance, gymnasium_success="reached_time_limit"
    )
    assert cfg.evaluation.max_steps == 100 and "max_steps" not in cfg.evaluation.model_fields_set
    assert (ds.lengths - 1 == 500).all() and ds.success.all()  # survivors, not cut at 100
    notes = [r.getMessage() for r in pcpg_log.records if "rollouts run up to" in r.getMessage()]
    assert notes == [
        "trajectories: rollouts run up to 500 steps, the longest logged trajectory "
        "(evaluation.max_steps not set)"
    ]
    assert not [r for r in pcpg_log.records if r.levelname == "WARNING"]  # the env's limit is 500


def test_a_user_set_max_steps_is_honoured(tmp_path, cartpole_parquet, pcpg_log) -> None:
    from pcpg_dist.domains import contract

    path = write_config(
        tmp_path,
        cartpole_parquet,
        trajectories={"path": str(cartpole_parquet), "gymnasium_env": "CartPole-v1"},
        evaluation={"max_steps": 100, "rollouts_per_policy": 20},
    )
    cfg = load_config(path)
    units = contract.units(cfg, contract.generate(cfg, show_progress=False))
    ds = contract.hooks(cfg, units[0].name).rollout(balance, 2, np.random.default_rng(0))
    assert (ds.lengths - 1 == 100).all() and not ds.success.any()  # default rule: not terminated
    assert not [r for r in pcpg_log.records if "rollouts run up to" in r.getMessage()]
    # a config that never went through units() (a worker's copy) reads the logs for the length
    fresh = load_config(
        write_config(
            tmp_path,
            cartpole_parquet,
            **{"trajectories": {"path": str(cartpole_parquet), "gymnasium_env": "CartPole-v1"}},
        )
    )
    ds = contract.hooks(fresh, units[0].name).rollout(balance, 1, np.random.default_rng(0))
    assert ds.lengths[0] - 1 == 500


def test_reached_time_limit_marks_survivors_as_successes_and_fallen_poles_as_failures(
    tmp_path, cartpole_parquet
) -> None:
    ds, _ = cartpole_rollout(
        tmp_path, cartpole_parquet, push_left, gymnasium_success="reached_time_limit"
    )
    assert (ds.lengths - 1 < 100).all() and not ds.success.any()  # the pole fell: terminated


def test_an_env_time_limit_shorter_than_the_logs_warns_naming_both_numbers(
    tmp_path, cartpole_parquet, pcpg_log
) -> None:
    ds, _ = cartpole_rollout(
        tmp_path,
        cartpole_parquet,
        balance,
        n=2,
        gymnasium_kwargs={"max_episode_steps": 200},
        gymnasium_success="reached_time_limit",
    )
    warnings = [r.getMessage() for r in pcpg_log.records if r.levelname == "WARNING"]
    assert warnings == [
        "trajectories: CartPole-v1 ends episodes after 200 steps (its time limit) but the longest "
        "logged trajectory has 500; rollouts stop at 200 unless trajectories.gymnasium_kwargs "
        "raises it: gymnasium_kwargs: {max_episode_steps: 500}"
    ]
    assert (ds.lengths - 1 == 200).all() and ds.success.all()  # truncated by the limit: survived


def test_the_evaluation_key_follows_the_rollout_settings(tmp_path, cartpole_parquet) -> None:
    """A changed success rule, or logs longer than evaluation.max_steps's default, make another
    evaluation key (a cached evaluation cut at 100 steps was reused); without a rollout env the
    key is the one every other domain has (nothing added)."""
    from pcpg_dist.pipeline.declared import evaluate_key

    def key(**over) -> str:
        trajectories = {"path": str(cartpole_parquet), **over}
        cfg = load_config(write_config(tmp_path, cartpole_parquet, trajectories=trajectories))
        return evaluate_key(["t"], cfg)

    plain = key()
    survive = key(gymnasium_env="CartPole-v1", gymnasium_success="reached_time_limit")
    terminate = key(gymnasium_env="CartPole-v1")
    assert len({plain, survive, terminate}) == 3
    assert terminate == key(gymnasium_env="CartPole-v1")  # a fixed function of the settings
