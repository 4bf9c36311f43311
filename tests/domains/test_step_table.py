"""The step table as docs/bring-your-own-data.md promises it: rows in any order, one clear line per
problem (a repeated t, a null inside a `valid` list, a CSV or JSON file, rewards whose sum
overflows), integer columns stored as whole-number floats."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from test_trajectories import tiny_table, write_config

from pcpg_dist.cli import main
from pcpg_dist.common.errors import DataError
from pcpg_dist.dataset import Dataset, bool_lists, load_dataset
from pcpg_dist.domains.defaults import score_dataset
from pcpg_dist.domains.trajectories.table import datasets_from_table
from pcpg_dist.domains.trajectories.table_files import read_step_table
from pcpg_dist.stages.ranking import RankConfig


def full_table() -> pd.DataFrame:
    """tiny_table() with string ids, valid lists, styles, success and a skill column, and two
    trajectories whose last row still has an action (they get a closing row)."""
    df = tiny_table(n_traj=8, steps=5, seed=3)
    df = df[~((df.trajectory < 2) & (df.action == -1))].reset_index(drop=True)
    df["valid"] = [
        [i == a or (i + t) % 2 == 0 for i in range(3)] for a, t in zip(df.action, df.t, strict=True)
    ]
    df["style"] = df.trajectory % 3
    df["success"] = df.trajectory % 2 == 0
    df["skill"] = df.trajectory * 1.5
    df["trajectory"] = "p" + df.trajectory.astype(str)
    return df


def read(path: Path) -> Dataset:
    (ds,) = datasets_from_table(read_step_table(path), skill_column="skill").values()
    return ds


def assert_same(a: Dataset, b: Dataset) -> None:
    for name in (
        "states",
        "actions",
        "valid",
        "rewards",
        "offsets",
        "trajectory_ids",
        "styles",
        "success",
        "epsilon",
        "skill",
        "source_ids",
    ):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None) and (x is None or x.dtype == y.dtype), name
        np.testing.assert_array_equal(x, y, err_msg=name)
    assert (a.n_actions, a.feature_names, a.domain) == (b.n_actions, b.feature_names, b.domain)


# ------------------------------------------------------------------ 1. rows in any order
def test_shuffled_rows_give_exactly_the_dataset_of_the_sorted_rows(tmp_path) -> None:
    """A shuffled table was refused: `column 't', row 481: t = 3 does not increase within trajectory 'p0'`."""
    df = full_table()
    df.to_parquet(tmp_path / "sorted.parquet", index=False)
    shuffled = df.sample(frac=1.0, random_state=4)
    shuffled.to_parquet(tmp_path / "shuffled.parquet", index=False)
    expected = read(tmp_path / "sorted.parquet")
    assert expected.n_trajectories == 8 and (expected.actions[expected.offsets[1:] - 1] == -1).all()
    assert_same(read(tmp_path / "shuffled.parquet"), expected)
    shuffled.to_parquet(tmp_path / "with_index.parquet")  # pandas' own index column is ignored
    assert_same(read(tmp_path / "with_index.parquet"), expected)
    folder = tmp_path / "logs"  # a folder of three files, each shuffled, trajectories going on from
    folder.mkdir()  # one file into the next (t going on): the sorted table cut in three
    for i, part in enumerate(np.array_split(np.arange(len(df)), 3)):
        df.iloc[part].sample(frac=1.0, random_state=i).to_parquet(
            folder / f"part-{i}.parquet", index=False
        )
    assert (
        df.iloc[np.array_split(np.arange(len(df)), 3)[1]].trajectory.nunique()
        < df.trajectory.nunique()
    )
    assert_same(read(folder), expected)


def test_a_repeated_t_names_the_trajectory_the_file_and_both_rows(tmp_path) -> None:
    df = full_table().sample(frac=1.0, random_state=4).reset_index(drop=True)
    first, second = (int(i) for i in np.flatnonzero((df.trajectory == "p3").to_numpy())[[2, 5]])
    df.loc[second, "t"] = df.t[first]
    path = tmp_path / "logs.parquet"
    df.to_parquet(path, index=False)
    with pytest.raises(DataError) as e:
        read(path)
    i, j = sorted((first, second))
    assert str(e.value) == (
        f"{path}: column 't', rows {i} and {j}: trajectory 'p3' has two rows with "
        f"t = {df.t[first]}; each step of a trajectory needs its own t"
    )
    folder = tmp_path / "logs"  # in a folder: the file and its own rows
    folder.mkdir()
    df = full_table()
    df.iloc[:10].to_parquet(folder / "a.parquet", index=False)  # p0 and p1
    second = df.iloc[10:].reset_index(drop=True)
    assert (second.trajectory[3], second.t[3], second.trajectory[7]) == ("p2", 3, "p3")
    second.loc[7, ["trajectory", "t"]] = ["p2", 3]
    second.to_parquet(folder / "b.parquet", index=False)
    with pytest.raises(DataError) as e:
        read(folder)
    assert str(e.value) == (
        f"{folder / 'b.parquet'}: column 't', rows 3 and 7: trajectory 'p2' has two rows "
        f"with t = 3; each step of a trajectory needs its own t"
    )


# ------------------------------------------------------------------ 2. a null inside a valid list
def test_a_null_inside_a_valid_list_names_the_file_its_row_and_trajectory(tmp_path) -> None:
    """It said `column 'valid' has null entries inside its lists`, with no row."""
    lists = [[True, True, True]] * 30
    lists[7] = [True, None, True]
    table = pa.Table.from_pandas(tiny_table(), preserve_index=False).append_column(
        "valid", pa.array(lists, pa.list_(pa.bool_()))
    )
    path = tmp_path / "logs.parquet"
    pq.write_table(table, path)
    with pytest.raises(DataError) as e:
        datasets_from_table(read_step_table(path))
    assert str(e.value) == (
        f"{path}: column 'valid', row 7: a null entry in the list (trajectory 1); every "
        f"entry must be true or false"
    )
    folder = tmp_path / "logs"
    folder.mkdir()
    pq.write_table(table.slice(0, 5), folder / "a.parquet")
    pq.write_table(table.slice(5), folder / "b.parquet")
    with pytest.raises(DataError) as e:
        datasets_from_table(read_step_table(folder))
    assert str(e.value).startswith(
        f"{folder / 'b.parquet'}: column 'valid', row 2: a null entry"
    ), str(e.value)
    # pcpg's own datasets (dataset.bool_lists): the row too, for fixed-size and plain lists
    for column in (
        pa.array([[True, False], [None, True]], pa.list_(pa.bool_(), 2)),
        pa.array([[True, False], [True, None]], pa.list_(pa.bool_())),
    ):
        with pytest.raises(DataError) as e:
            bool_lists(column, 2, "toy-E1.parquet")
        assert (
            str(e.value)
            == "toy-E1.parquet: column 'valid', row 1: a null entry in the list; every entry "
            "must be true or false"
        )


# ------------------------------------------------------------------ 3. a file that is not Parquet
@pytest.mark.parametrize(
    "name, reader",
    [("grid.csv", "pandas.read_csv(path)"), ("grid.jsonl", "pandas.read_json(path, lines=True)")],
)
def test_a_csv_or_json_lines_file_is_told_what_is_read_and_how_to_convert_it(
    tmp_path, capsys, name, reader
) -> None:
    """It said `not a readable Parquet file (Parquet magic bytes not found in footer ...)`."""
    path = tmp_path / name
    df = tiny_table()
    df.to_csv(path, index=False) if name.endswith(".csv") else df.to_json(
        path, orient="records", lines=True
    )
    code = main(
        ["generate", str(write_config(tmp_path, path)), "--out", str(tmp_path / "out"), "--quiet"]
    )
    err = capsys.readouterr().err.strip()
    kind = Path(name).suffix[1:].upper()
    assert code == 2 and err == (
        f"pcpg: error: {path}: not a Parquet file: trajectories.path reads Parquet (a "
        f"file or a folder of them) or minari:DATASET_ID; a {kind} file converts to "
        f"Parquet with {reader}.to_parquet(...)"
    ), err
    assert not (tmp_path / "out").exists()
    with pytest.raises(DataError) as e:  # pcpg's own datasets (pcpg classify): what writes them
        load_dataset(path)
    assert str(e.value).startswith(
        f"{path}: not a Parquet file: this reads pcpg datasets, which `pcpg "
        f"generate CONFIG --out DIR` writes from a Parquet step table"
    ), str(e.value)
    # once converted as told, the file is a step table
    parquet = tmp_path / "grid.parquet"
    (pd.read_csv(path) if name.endswith(".csv") else pd.read_json(path, lines=True)).to_parquet(
        parquet
    )
    assert read_step_table(parquet).table.num_rows == 30


def test_a_raw_step_table_given_as_a_pcpg_dataset_points_to_pcpg_generate(tmp_path) -> None:
    """`pcpg classify MODEL logs.parquet` on a user's own log: the way to make a dataset of it."""
    path = tmp_path / "logs.parquet"
    tiny_table().to_parquet(path, index=False)
    with pytest.raises(DataError) as e:
        load_dataset(path)
    assert str(e.value) == (
        f"{path}: not a pcpg dataset (no 'pcpg' schema metadata); a step table of your own "
        f"logs becomes pcpg datasets with `pcpg generate CONFIG --out DIR` (domain: "
        f"trajectories, docs/bring-your-own-data.md)"
    )


# ------------------------------------------------------------------ 4. rewards whose sum overflows
def test_rewards_whose_sum_overflows_are_refused_at_load_before_anything_is_written(
    tmp_path, capsys
) -> None:
    """Two rewards of 1e308 in one trajectory printed numpy's `RuntimeWarning: overflow encountered
    in reduceat` and, after the data cache was written, `the skill score of trajectory 0 is inf`."""
    df = tiny_table()
    df.loc[[6, 8], "reward"] = 1e308  # trajectory 1
    path = tmp_path / "logs.parquet"
    df.to_parquet(path, index=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's overflow warning would be an exception
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
    assert code == 2 and err == (
        f"pcpg: error: {path}: column 'reward', row 6: the rewards of trajectory 1 add "
        f"up beyond a 64-bit float (the largest, 1e+308, is in this row); scale the "
        f"rewards down so that each trajectory's sum is finite"
    ), err
    assert not (tmp_path / "runs").exists()  # no data cache


def test_a_return_that_overflows_is_inf_without_a_numpy_warning() -> None:
    """A dataset from elsewhere (a domain's generator): Step B's own check reports it, in one line."""
    ds = Dataset.from_trajectories(
        "toy",
        "E1",
        2,
        [
            {
                "states": np.zeros((3, 1)),
                "actions": [0, 1],
                "valid": np.ones((3, 2), bool),
                "rewards": [1e308, 1e308],
            }
        ],
        styles=[0],
        success=[True],
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert ds.returns.tolist() == [np.inf]
        with pytest.raises(DataError, match="the skill score of trajectory 0 is inf"):
            score_dataset(ds, RankConfig(), score=lambda d: d.returns)


# ------------------------------------------------------------------ 5. integer columns stored as floats
def test_whole_number_floats_are_integers_and_a_fractional_trajectory_id_is_refused(
    tmp_path,
) -> None:
    df = tiny_table()
    df.to_parquet(tmp_path / "ints.parquet", index=False)
    as_floats = df.astype({"trajectory": float, "t": float, "action": float})
    as_floats.to_parquet(tmp_path / "floats.parquet", index=False)
    (a,) = datasets_from_table(read_step_table(tmp_path / "ints.parquet")).values()
    (b,) = datasets_from_table(read_step_table(tmp_path / "floats.parquet")).values()
    assert_same(a, b)
    as_floats.loc[5, "trajectory"] = 1.5
    as_floats.to_parquet(tmp_path / "bad.parquet", index=False)
    with pytest.raises(DataError) as e:
        datasets_from_table(read_step_table(tmp_path / "bad.parquet"))
    assert (
        str(e.value)
        == f"{tmp_path / 'bad.parquet'}: column 'trajectory', row 5: 1.5 is not an integer"
    )


def test_env_values_that_become_one_unit_name_are_named_as_the_user_wrote_them(tmp_path) -> None:
    """Non-ASCII env values all clean to 'env': the message showed ['env', 'env', 'env'] and blamed
    "characters other than letters" for the letters 日本; it names the values and what they become."""
    df = full_table()
    df["env"] = np.where(
        df.trajectory.isin(["p0", "p1", "p2"]),
        "日本",
        np.where(df.trajectory == "p3", "中国", "E1"),
    )
    path = tmp_path / "logs.parquet"
    df.to_parquet(path, index=False)
    with pytest.raises(DataError) as e:
        datasets_from_table(read_step_table(path))
    assert str(e.value) == (
        f"{path}: column 'env': the values ['日本', '中国'] all become the unit name 'env' "
        "(unit names name folders and files: they keep the ASCII letters, digits, '_', '.', "
        "'+' and '-' of a value); rename them"
    )


def test_string_trajectory_ids_come_back_from_generate_and_classify(tmp_path, capsys) -> None:
    """Ids like 'p10' were numbered 0..n-1 in sorted order and lost: `pcpg classify` wrote
    0, 1, 2, ... that could not be joined back to the user's episodes."""
    from pcpg_dist.dataset import write_parquet
    from pcpg_dist.stages.clustering import ClusterConfig, cluster

    df = full_table()
    path = tmp_path / "logs.parquet"
    df.to_parquet(path, index=False)
    ds = read(path)
    assert list(ds.source_ids) == sorted(
        df.trajectory.unique()
    )  # numbered in sorted order, names kept
    assert list(ds.subset(np.array([2, 0])).source_ids) == [ds.source_ids[2], ds.source_ids[0]]
    write_parquet(ds, tmp_path / "data.parquet")
    back = load_dataset(tmp_path / "data.parquet")
    assert list(back.source_ids) == list(ds.source_ids)
    cluster(ds, ClusterConfig(k=2, method="visits_kmeans"), seed=0).model.save(tmp_path / "model")
    out = tmp_path / "styles.csv"
    assert (
        main(
            ["classify", str(tmp_path / "model"), str(tmp_path / "data.parquet"), "--out", str(out)]
        )
        == 0
    )
    assert pd.read_csv(out)["trajectory"].tolist() == list(ds.source_ids)
    int_ids = tiny_table(n_traj=4, steps=3, seed=0)
    int_ids.to_parquet(tmp_path / "ints.parquet", index=False)
    (plain,) = datasets_from_table(read_step_table(tmp_path / "ints.parquet")).values()
    assert plain.source_ids is None  # integer ids are kept as they are


def test_actions_never_taken_below_the_largest_are_said_once(tmp_path, caplog) -> None:
    """One stray action 9 in logs of actions 0..2 made every agent choose among 10 actions, and the
    random baseline fell from 0.333 to 0.100, without a word."""
    import logging

    df = tiny_table(n_traj=6, steps=4, seed=0)
    df = df.drop(columns=[c for c in ("valid",) if c in df])
    path = tmp_path / "logs.parquet"
    df.to_parquet(path, index=False)
    with caplog.at_level(logging.WARNING, logger="pcpg_dist"):
        datasets_from_table(read_step_table(path))
    assert caplog.records == []  # every action id below the largest is taken
    stray = df.index[df.action >= 0][3]
    df.loc[stray, "action"] = 9
    df.to_parquet(path, index=False)
    with caplog.at_level(logging.WARNING, logger="pcpg_dist"):
        (ds,) = datasets_from_table(read_step_table(path)).values()
    assert ds.n_actions == 10  # the documented rule still holds
    assert [r.getMessage() for r in caplog.records] == [
        f"{path}: 6 of the 10 actions ([3, 4, 5, 6, 7, 8]) are never taken; their number comes from the largest "
        f"action, 9 (row {stray}): set trajectories.n_actions if that is not right"
    ]
