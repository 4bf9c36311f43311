"""Bad input and tampering: every failure is the project's own clear error, never a traceback,
and nothing the project loads from disk can execute code."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pcpg_dist.cli import main
from pcpg_dist.common.errors import ConfigError, DataError, LayoutError, PcpgError, TrainingError
from pcpg_dist.config import parse_config
from pcpg_dist.domains.gridworld.layout import parse_layout

ROOT = Path(__file__).resolve().parent.parent

scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**6), 10**6),
    st.floats(allow_nan=True),
    st.text(max_size=12),
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=10,
)
SECTIONS = [
    "name",
    "domain",
    "seed",
    "seeds",
    "gridworld",
    "pbtg",
    "clustering",
    "ranking",
    "bc",
    "evaluation",
    "runner",
    "minidungeons",
    "mario",
    "bogus",
]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.dictionaries(st.sampled_from(SECTIONS), values, max_size=6))
def test_random_configs_fail_only_with_config_error(data):
    try:
        parse_config(data, base_dir=ROOT / "experiments")
    except ConfigError as e:
        assert "\n" not in str(e)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.text(alphabet=".#SGX12Z\t ", min_size=0, max_size=12), min_size=0, max_size=12))
def test_random_layouts_fail_only_with_layout_error(rows):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            parse_layout("\n".join(rows), name="fuzz.txt")
        except LayoutError as e:
            assert "fuzz.txt" in str(e)


@pytest.mark.parametrize(
    "patch, needle",
    [
        ({"ranking": {"ps": [1.5]}}, "ranking.ps"),
        ({"ranking": {"ps": [0.0]}}, "ranking.ps"),
        ({"clustering": {"k": 0}}, "clustering.k"),
        ({"bc": {"epochs": -1}}, "bc.epochs"),
    ],
)
def test_issue_listed_bad_values_exit_2_and_start_nothing(tmp_path, capsys, patch, needle):
    cfg = {
        "name": "bad",
        "gridworld": {"layout_dir": str(ROOT / "pcpg_dist" / "data" / "gridworld")},
        **patch,
    }
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(cfg))
    assert main(["run", str(path), "--workdir", str(tmp_path / "runs"), "--no-tracking"]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and err.count("\n") == 0
    assert not (tmp_path / "runs").exists()


class Boom:
    def __reduce__(self):
        return (Path("/tmp/pcpg-pwned").touch, ())


def test_tampered_model_file_is_rejected_not_executed(tmp_path):
    from pcpg_dist.config.stages import BCConfig
    from pcpg_dist.stages.bc import TrainedCells, train_cells
    from pcpg_dist.stages.ranking import RankConfig, plan_cells
    from tests.bc_toy import make_dataset

    ds = make_dataset(n_per_style=10)
    cells = plan_cells(ds, ds.styles, np.arange(ds.n_trajectories), RankConfig(ps=(1.0,)), [0])
    trained = train_cells(cells[:1], BCConfig(epochs=5))
    path = trained.save(tmp_path / "cells")
    TrainedCells.load(path)  # the genuine file loads
    sentinel = Path("/tmp/pcpg-pwned")
    sentinel.unlink(missing_ok=True)
    torch.save({"W0": Boom()}, path)  # a pickle payload where tensors should be
    with pytest.raises(DataError, match="unreadable model files"):
        TrainedCells.load(path)
    assert not sentinel.exists()


def test_tampered_cluster_model_is_rejected(tmp_path):
    from pcpg_dist.dataset import Dataset
    from pcpg_dist.stages.clustering import ClusterConfig, cluster, load_model

    rng = np.random.default_rng(0)
    trajs = [
        {
            "states": rng.random((4, 2)),
            "actions": np.zeros(3, int),
            "valid": np.full(4, 1),
            "rewards": np.zeros(3),
        }
        for _ in range(12)
    ]
    ds = Dataset.from_trajectories("toy", "E", 1, trajs, styles=[0] * 12, success=[True] * 12)
    res = cluster(ds, ClusterConfig(method="summary_kmeans", k=2), seed=0)
    res.model.save(tmp_path / "m")
    pt = next((tmp_path / "m").glob("*.pt"))
    pt.write_bytes(pickle.dumps(Boom()))
    with pytest.raises(DataError):
        load_model(tmp_path / "m")
    assert not Path("/tmp/pcpg-pwned").exists()


def test_unwritable_output_is_a_clear_error(tmp_path, capsys):
    """An output path that cannot be created (here: below a plain file) is a one-line error."""
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("x")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "name": "w",
                "gridworld": {
                    "layout_dir": str(ROOT / "pcpg_dist" / "data" / "gridworld"),
                    "environments": ["E1"],
                },
                "pbtg": {"episodes": 10, "trajectories_per_style": 5, "dataset_per_style": 5},
            }
        )
    )
    code = main(["generate", str(cfg), "--out", str(blocker / "data"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and err.startswith("pcpg: error: cannot access") and "not-a-folder" in err


def test_project_errors_are_one_family():
    for cls in (ConfigError, DataError, LayoutError, TrainingError):
        assert issubclass(cls, PcpgError)


# ---------------------------------------------------------------- issue 18: files and training
@pytest.mark.parametrize("engine", ["numba", "torch"])
def test_diverged_training_stops_with_one_line_and_returns_no_weights(engine):
    """States near float32's limit overflow the input scaling: the weights turn NaN. That used to be
    published as agents with exit 0; now training raises before anything is returned."""
    import dataclasses

    from pcpg_dist.config.stages import BCConfig
    from pcpg_dist.domains.defaults import split_trajectories
    from pcpg_dist.stages.bc import train_cells
    from pcpg_dist.stages.ranking import RankConfig, plan_cells
    from tests.bc_toy import make_dataset

    ds = make_dataset(n_per_style=10)
    ds = dataclasses.replace(ds, states=ds.states * np.float32(3e37))
    train, _ = split_trajectories(ds.n_trajectories, 0.2, 0)
    with np.errstate(all="ignore"):
        cells = plan_cells(ds, ds.styles, train, RankConfig(ps=(1.0,)), seeds=[0])
        with pytest.raises(TrainingError) as e:
            train_cells(cells, BCConfig(epochs=20, engine=engine))
    msg = str(e.value)
    assert f"diverged for {len(cells)} of {len(cells)} cells (first: {cells[0].key})" in msg
    assert "bc.lr=0.01" in msg and "\n" not in msg


def write_log(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "play.log"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "text, needle",
    [
        (
            "0,0,0,0,0,3|99999999999999999999999,0,0,0,0,4|#0,0,0#\n",
            "step 1: counter above 16777216",
        ),
        ("0,0,0,0,0,3|1,0,0,0,0,-5|1,0,0,0,0,4|#0,0,0#\n", "step 1: event id -5 outside 0..38"),
    ],
)
def test_mario_log_overflow_and_negative_event_name_the_step(tmp_path, text, needle):
    from pcpg_dist.domains.mario.log import load_play_log

    with pytest.raises(DataError) as e:
        load_play_log(write_log(tmp_path, text))
    assert "play.log:1: episode 0 " + needle in str(e.value) and "\n" not in str(e.value)


def test_mario_log_that_is_not_a_regular_file_is_refused_at_once():
    from pcpg_dist.domains.mario.log import load_play_log

    with pytest.raises(DataError, match="/dev/zero: cannot read play log .not a regular file"):
        load_play_log("/dev/zero")


def test_non_utf8_layout_is_a_layout_error(tmp_path):
    from pcpg_dist.domains.gridworld.layout import load_layout

    path = tmp_path / "E1.txt"
    path.write_bytes(b"S.\xff\n.G\n")
    with pytest.raises(LayoutError, match="E1.txt: not UTF-8 text .byte 2."):
        load_layout(path)


@pytest.mark.parametrize(
    "stage, props, needle",
    [
        (b"S\xffE\n", b"{}", "stage.txt:1: not a UTF-8 text file"),
        (None, b"[" * 100_000, "props.json:1: JSON nested too deeply"),
        (
            None,
            b'{"PLAYER_MAX_HP": 1e300, "ENEMY_POWER": 1, "POTION_POWER": 1}',
            "'PLAYER_MAX_HP' must be a positive integer of at most 1000000",
        ),
    ],
)
def test_minidungeons_level_files_are_bounded(tmp_path, stage, props, needle):
    from pcpg_dist.domains.minidungeons.level import data_dir, read_level

    stage_path, props_path = tmp_path / "stage.txt", tmp_path / "props.json"
    stage_path.write_bytes(
        stage if stage is not None else (data_dir() / "stages" / "test.txt").read_bytes()
    )
    props_path.write_bytes(props)
    with pytest.raises(LayoutError) as e:
        read_level(stage_path, props_path)
    assert needle in str(e.value) and "\n" not in str(e.value)


def test_cluster_refuses_a_dataset_whose_env_would_leave_out(tmp_path, capsys, ray_session):
    """A dataset's metadata named its env '../../evil' and `pcpg cluster` wrote outside --out."""
    import json

    import pyarrow.parquet as pq

    from pcpg_dist.common.files import sha256_file
    from pcpg_dist.dataset import write_datasets
    from tests.bc_toy import make_dataset

    data = tmp_path / "deep" / "data"
    write_datasets(data, [make_dataset(n_per_style=5)], {})
    file = next(data.glob("*.parquet"))
    table = pq.read_table(file)
    meta = json.loads(table.schema.metadata[b"pcpg"])
    pq.write_table(
        table.replace_schema_metadata({"pcpg": json.dumps({**meta, "env": "../../evil"})}), file
    )
    manifest = json.loads((data / "manifest.json").read_text())
    manifest["files"][file.name]["sha256"] = sha256_file(
        file
    )  # a crafted, consistently signed dataset
    (data / "manifest.json").write_text(json.dumps(manifest))
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        yaml.safe_dump({"name": "c", "domain": "mario", "clustering": {"method": "summary_kmeans"}})
    )
    out = tmp_path / "deep" / "out"
    assert main(["cluster", str(cfg), "--data", str(data), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "metadata env '../../evil' is not a plain name" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.yaml", "deep"] and not out.exists()


@pytest.mark.parametrize(
    "style, needle",
    [
        (10**12, "style 1000000000000; styles are 0, 1, 2, ... (below 100000)"),
        (-5, "style -5; styles are 0, 1, 2"),
    ],
)
def test_step_table_style_out_of_range_names_the_row(tmp_path, style, needle):
    """A style id indexes count tables (np.bincount in the ceiling): 10**12 would ask for terabytes."""
    import pyarrow as pa

    from pcpg_dist.domains.trajectories.table import datasets_from_table
    from pcpg_dist.domains.trajectories.table_files import StepTable

    table = pa.table(
        {
            "trajectory": [0, 0, 1, 1],
            "t": [0, 1, 0, 1],
            "action": [0, -1, 1, -1],
            "s0": [0.0, 1.0, 0.0, 1.0],
            "style": [0, 0, style, style],
        }
    )
    with pytest.raises(DataError) as e:
        datasets_from_table(StepTable(table, "logs.parquet", "logs"))
    assert f"logs.parquet: column 'style', row 2: {needle}" in str(e.value)


def test_step_table_with_an_env_per_row_is_refused(tmp_path):
    import pyarrow as pa

    from pcpg_dist.domains.trajectories.table import MAX_ENVS, datasets_from_table
    from pcpg_dist.domains.trajectories.table_files import StepTable

    n = MAX_ENVS + 1
    table = pa.table(
        {
            "trajectory": np.arange(n),
            "t": np.zeros(n, np.int64),
            "action": np.full(n, -1),
            "s0": np.zeros(n),
            "env": [f"e{i}" for i in range(n)],
        }
    )
    with pytest.raises(
        DataError,
        match=f"logs.parquet: column 'env' has {n} distinct values; .* at most {MAX_ENVS}",
    ):
        datasets_from_table(StepTable(table, "logs.parquet", "logs"))


@pytest.mark.parametrize(
    "edit",
    [
        lambda m: {**m, "config": [1]},
        lambda m: {**m, "state_dim": 10**400},
        lambda m: {**m, "feature_names": 5},
        lambda m: {**m, "config": {**m["config"], "hidden_size": -1}},
        lambda m: {**m, "config": {**m["config"], "hidden_size": 10**6}},
        lambda m: "[" * 100_000,
    ],
)
def test_tampered_cluster_model_is_one_line(tmp_path, edit):
    """A hand-edited cluster_model.json is a one-line DataError, never a traceback or a huge
    allocation (issue 18: tampered `cluster_model.json`)."""
    import json as json_lib

    from pcpg_dist.common.errors import DataError
    from pcpg_dist.config import ClusterConfig
    from pcpg_dist.domains.gridworld.layout import random_layouts
    from pcpg_dist.domains.gridworld.pbtg import assemble_dataset, generate_pair
    from pcpg_dist.domains.gridworld.settings import PBTGConfig
    from pcpg_dist.stages.clustering import cluster, load_model

    layout = random_layouts(1, 5)[0]
    pbtg = PBTGConfig(episodes=2000, trajectories_per_style=30, dataset_per_style=15)
    ds = assemble_dataset([generate_pair(layout, r, pbtg, 0) for r in range(4)])
    cluster(ds, ClusterConfig(method="bag_kmeans", k=4), 0).model.save(tmp_path / "m")
    meta_path = tmp_path / "m" / "cluster_model.json"
    edited = edit(json_lib.loads(meta_path.read_text()))
    meta_path.write_text(edited if isinstance(edited, str) else json_lib.dumps(edited))
    with pytest.raises(DataError) as info:
        load_model(tmp_path / "m")
    assert "\n" not in str(info.value) and len(str(info.value)) < 600
