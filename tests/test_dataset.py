"""The Parquet + manifest interchange format: round trip, validation, corruption detection."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pcpg_dist.common.errors import DataError
from pcpg_dist.dataset import Dataset, load_dataset, load_datasets, read_parquet, write_datasets


def small(env: str = "E1", n: int = 5, seed: int = 0) -> Dataset:
    rng = np.random.default_rng(seed)
    trajs = []
    for _ in range(n):
        T = int(rng.integers(0, 6))
        trajs.append(
            {
                "states": rng.random((T + 1, 3)),
                "actions": rng.integers(0, 4, T),
                "valid": np.full(T + 1, 15),
                "rewards": rng.random(T),
            }
        )
    return Dataset.from_trajectories(
        "toy",
        env,
        4,
        trajs,
        styles=rng.integers(0, 2, n),
        success=rng.random(n) < 0.5,
        epsilon=rng.random(n),
        feature_names=("a", "b", "c"),
    )


def same(a: Dataset, b: Dataset) -> None:
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
    ):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert (a.domain, a.env, a.n_actions, a.feature_names) == (
        b.domain,
        b.env,
        b.n_actions,
        b.feature_names,
    )


def test_round_trip_and_plain_pandas(tmp_path):
    ds = [small("E1"), small("E2", seed=1)]
    write_datasets(tmp_path, ds, {"config": {"x": 1}})
    loaded = load_datasets(tmp_path)
    same(loaded["E1"], ds[0])
    same(loaded["E2"], ds[1])
    df = pd.read_parquet(tmp_path / "toy-E1.parquet")
    assert list(df.columns[:4]) == ["trajectory", "t", "env", "style"]
    assert (df.groupby("trajectory")["action"].last() == -1).all()
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["files"]["toy-E1.parquet"]["rows"] == ds[0].n_rows


def test_subset_and_concat(rng):
    ds = small(n=8)
    sub = ds.subset([5, 2])
    assert sub.n_trajectories == 2
    np.testing.assert_array_equal(sub.trajectory_states(0), ds.trajectory_states(5))
    np.testing.assert_array_equal(sub.trajectory_states(1), ds.trajectory_states(2))
    both = Dataset.concat([ds, sub])
    assert both.n_trajectories == 10 and both.n_rows == ds.n_rows + sub.n_rows
    assert ds.valid_mask.shape == (ds.n_rows, 4) and ds.valid_mask.all()


def test_bit_flip_and_truncation_detected(tmp_path):
    write_datasets(tmp_path, [small()], {})
    path = tmp_path / "toy-E1.parquet"
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    path.write_bytes(bytes(raw))
    with pytest.raises(DataError, match="toy-E1.parquet: content hash"):
        load_datasets(tmp_path)
    path.write_bytes(bytes(raw[: len(raw) // 3]))
    with pytest.raises(DataError, match="toy-E1.parquet: not a readable Parquet"):
        read_parquet(path)


def test_corrupt_parquet_bytes_are_one_printable_line(tmp_path):
    """Arrow's text for a corrupt page or footer spans lines and holds raw thrift bytes (`don't know
    what type: \\x0f`): every 64-byte corruption of a dataset file is now one printable line."""
    path = tmp_path / "toy-E1.parquet"
    write_datasets(tmp_path, [small()], {})
    raw = path.read_bytes()
    escaped = 0
    for offset in range(0, len(raw) - 64, 16):
        flipped = bytearray(raw)
        flipped[offset : offset + 64] = bytes(b ^ 0xFF for b in flipped[offset : offset + 64])
        path.write_bytes(bytes(flipped))
        try:
            read_parquet(path)  # no manifest check here: some flips only change values
        except DataError as e:
            text = str(e)
            assert text.startswith(f"{path}: ") and text.isprintable() and len(text) < 400, text
            escaped += "\\x" in text
    assert escaped  # the case that printed a control byte on its own line is among them


@pytest.mark.parametrize(
    "mutate, needle",
    [
        (
            lambda t: t.set_column(
                t.schema.get_field_index("action"),
                "action",
                pa.array(t.column("action").to_numpy().astype("float64")),
            ),
            "column 'action' has type double",
        ),
        (lambda t: t.drop(["reward"]), "missing column 'reward'"),
        (
            lambda t: t.set_column(
                t.schema.get_field_index("s0"),
                "s0",
                pa.array(np.where(np.arange(t.num_rows) == 3, np.nan, 0).astype("float32")),
            ),
            "NaN or infinite",
        ),
        (
            lambda t: t.filter(pa.array(np.arange(t.num_rows) != 1)),
            "missing or repeated time steps",
        ),
    ],
)
def test_bad_files_name_the_problem(tmp_path, mutate, needle):
    table = small(n=3).to_table()
    path = tmp_path / "bad.parquet"
    pq.write_table(mutate(table), path)
    with pytest.raises(DataError, match="bad.parquet") as e:
        load_dataset(path)
    assert needle in str(e.value)


def test_zero_length_trajectory_rejected():
    with pytest.raises(DataError, match="trajectory 1 has zero length"):
        Dataset(
            domain="toy",
            env="E",
            n_actions=2,
            states=np.zeros((2, 1), np.float32),
            actions=np.array([-1, -1]),
            valid=np.zeros((2, 2), bool),
            rewards=np.zeros(2),
            offsets=np.array([0, 1, 1, 2]),
            trajectory_ids=np.arange(3),
            styles=np.zeros(3, np.int64),
            success=np.zeros(3, bool),
            epsilon=np.zeros(3),
        )


def test_write_never_leaves_a_half_file(tmp_path, monkeypatch):
    write_datasets(tmp_path, [small()], {})
    before = (tmp_path / "toy-E1.parquet").read_bytes()

    def boom(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pq, "write_table", boom)
    with pytest.raises(OSError):
        write_datasets(tmp_path, [small(seed=3)], {})
    assert (tmp_path / "toy-E1.parquet").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["manifest.json", "toy-E1.parquet"]


# ---------------------------------------------------------------- hostile files (issue 18)
def with_meta(table: pa.Table, **changes) -> pa.Table:
    meta = json.loads(table.schema.metadata[b"pcpg"])
    meta.update(changes)
    return table.replace_schema_metadata({"pcpg": json.dumps(meta)})


def with_column(table: pa.Table, name: str, values: np.ndarray) -> pa.Table:
    i = table.schema.get_field_index(name)
    return table.set_column(i, name, pa.array(values, table.schema.field(name).type))


def action_at(table: pa.Table, row: int, value: int) -> np.ndarray:
    a = table.column("action").to_numpy().copy()
    a[row] = value
    return a


@pytest.mark.parametrize(
    "mutate, needle",
    [
        (lambda t: with_meta(t, env="../../evil"), "metadata env '../../evil' is not a plain name"),
        (lambda t: with_meta(t, env="/etc"), "metadata env '/etc' is not a plain name"),
        (lambda t: with_meta(t, domain="a/b"), "metadata domain 'a/b'"),
        (lambda t: with_meta(t, n_actions=1e12), "n_actions 1000000000000 outside 1..1000000"),
        (lambda t: with_meta(t, n_actions=float("inf")), "unreadable 'pcpg' schema metadata"),
        (lambda t: with_meta(t, feature_names=7), "unreadable 'pcpg' schema metadata"),
        (
            lambda t: t.replace_schema_metadata({"pcpg": "[" * 100_000}),
            "unreadable 'pcpg' schema metadata",
        ),
        (lambda t: with_column(t, "action", action_at(t, 0, -5)), "takes action -5, outside 0..3"),
        (lambda t: with_column(t, "style", np.full(t.num_rows, -7)), "has style -7"),
        (
            lambda t: with_column(t, "style", np.full(t.num_rows, 10**12)),
            "has style 1000000000000; styles are 0, 1, 2",
        ),
    ],
)
def test_hostile_dataset_files_are_one_line_data_errors(tmp_path, mutate, needle):
    table = small(n=3, seed=2).to_table()
    assert table.column("action").to_numpy()[0] >= 0  # row 0 is mid-trajectory
    path = tmp_path / "bad.parquet"
    pq.write_table(mutate(table), path)
    with pytest.raises(DataError, match="bad.parquet") as e:
        load_dataset(path)
    assert needle in str(e.value) and "\n" not in str(e.value) and len(str(e.value)) < 500


@pytest.mark.parametrize(
    "files, needle",
    [
        (
            ["toy-E1.parquet"],
            "'files' must map file names to their hashes (a JSON object), got list",
        ),
        (
            {"../toy-E1.parquet": {"sha256": "x", "rows": 1}},
            "manifest file '../toy-E1.parquet' is not a plain name",
        ),
        (
            {"/etc/passwd": {"sha256": "x", "rows": 1}},
            "manifest file '/etc/passwd' is not a plain name",
        ),
        ({"toy-E1.parquet": "abc"}, "entry 'toy-E1.parquet' must be a mapping"),
    ],
)
def test_manifest_entries_are_confined_and_typed(tmp_path, files, needle):
    write_datasets(tmp_path, [small()], {})
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    (tmp_path / "manifest.json").write_text(json.dumps({**manifest, "files": files}))
    with pytest.raises(DataError) as e:
        load_datasets(tmp_path)
    assert needle in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize(
    "content, needle",
    [
        (b"{not json", "unreadable manifest (JSONDecodeError"),
        (b"\xff\xfe{}", "unreadable manifest (UnicodeDecodeError"),
        (b"[" * 100_000, "unreadable manifest (RecursionError"),
        (b"[1, 2]", "unreadable manifest (TypeError"),
    ],
)
def test_garbage_manifest_is_one_line(tmp_path, content, needle):
    write_datasets(tmp_path, [small()], {})
    (tmp_path / "manifest.json").write_bytes(content)
    with pytest.raises(DataError) as e:
        load_datasets(tmp_path)
    assert needle in str(e.value) and "\n" not in str(e.value)


def test_a_manifest_entry_linking_outside_its_folder_is_refused(tmp_path):
    data, elsewhere = tmp_path / "data", tmp_path / "elsewhere"
    write_datasets(elsewhere, [small()], {})
    write_datasets(data, [small()], {})
    (data / "toy-E1.parquet").unlink()
    (data / "toy-E1.parquet").symlink_to(elsewhere / "toy-E1.parquet")
    with pytest.raises(DataError, match="toy-E1.parquet: a link to .*elsewhere.*outside"):
        load_datasets(data)


def test_a_dataset_path_that_is_not_a_regular_file_is_refused(tmp_path):
    with pytest.raises(DataError, match="/dev/zero: dataset file is not a regular file"):
        read_parquet("/dev/zero")


def test_memory_for_a_parquet_file_is_estimated_from_its_footer(tmp_path, monkeypatch):
    """Simulated small machine: the table's decoded size (from the footer) is compared with half
    the memory before a single row is read."""
    from pcpg_dist.common import memory as stages
    from pcpg_dist.domains.trajectories.table_files import read_step_table

    write_datasets(tmp_path, [small(n=50)], {})
    path = tmp_path / "toy-E1.parquet"
    assert load_dataset(path).n_trajectories == 50
    monkeypatch.setattr(stages, "machine_memory", lambda: 20_000)
    with pytest.raises(
        DataError, match=r"toy-E1.parquet: \d+ rows need about .* GiB of memory to load"
    ):
        load_dataset(path)
    with pytest.raises(DataError, match="split the data into smaller files"):
        read_step_table(path)


def test_a_write_that_cannot_happen_names_the_target_not_a_temporary_file(tmp_path, capsys):
    """`pcpg classify --out FOLDER` said `cannot access .FOLDER.ib_9sz9s.tmp: Is a directory`."""
    from pcpg_dist.common.files import atomic_write_bytes

    (tmp_path / "out").mkdir()
    with pytest.raises(IsADirectoryError) as e:
        atomic_write_bytes(tmp_path / "out", b"x")
    assert e.value.filename == str(tmp_path / "out") and list((tmp_path / "out").iterdir()) == []
    (tmp_path / "file").write_text("")
    with pytest.raises(OSError) as e:
        atomic_write_bytes(tmp_path / "file" / "below.csv", b"x")  # a folder that is a file
    assert e.value.filename == str(tmp_path / "file" / "below.csv")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "out"]


@pytest.mark.parametrize(
    "trajectory, says",
    [
        (
            {
                "states": np.zeros((3, 2)),
                "actions": [0, 1, 2],
                "valid": np.ones((4, 4), bool),
                "rewards": [0, 0, 0],
            },
            "dataset toy-E, trajectory 1: states of shape (3, 2) and actions of shape (3,); a trajectory of T "
            "actions has states of shape (T + 1, d), the last after the last action",
        ),
        (
            {
                "states": np.zeros((4, 2)),
                "actions": [0, 1, 2],
                "valid": np.ones((3, 4), bool),
                "rewards": [0, 0, 0],
            },
            "dataset toy-E, trajectory 1: valid must have shape (4, 4) (one mask per state), got (3, 4)",
        ),
        (
            {
                "states": np.zeros((4, 2)),
                "actions": [0, 1, 2],
                "valid": np.ones((4, 4), bool),
                "rewards": [0, 0],
            },
            "dataset toy-E, trajectory 1: rewards of shape (2,), expected (3,) (one per action)",
        ),
    ],
)
def test_a_trajectory_of_wrong_shapes_is_named_with_what_is_wrong(trajectory, says):
    """A plugin whose states were one row short was told "valid must have shape (9, 3), got (10, 3)":
    the wrong array unnamed, the right one blamed, no dataset or trajectory."""
    good = {
        "states": np.zeros((3, 2)),
        "actions": [0, 1],
        "valid": np.ones((3, 4), bool),
        "rewards": [0, 1],
    }
    with pytest.raises(DataError) as e:
        Dataset.from_trajectories(
            "toy", "E", 4, [good, trajectory], styles=[0, 1], success=[True, True]
        )
    assert str(e.value) == says
