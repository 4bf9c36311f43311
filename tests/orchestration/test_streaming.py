"""A log through the streamed pipeline on the tests' Ray: it finds the styles, its agents beat No
Clustering, the same seed gives the same numbers however the log is cut into blocks and files,
small logs stay in memory under 'auto', and bad rows inside a block reach the user as one line."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pcpg_dist.common.errors import DataError
from pcpg_dist.config import ExperimentConfig
from pcpg_dist.domains.sources import stream_source
from pcpg_dist.domains.trajectories.synthetic_log import write_styled_log


def config(path: Path, **over) -> ExperimentConfig:
    raw = {
        "name": "streamed",
        "domain": "trajectories",
        "seeds": [0],
        "trajectories": {"path": str(path), "stream": "on", **over.pop("trajectories", {})},
        "clustering": {"k": 4, "ceiling": False, "confidence_runs": 0},
        "ranking": {"ps": [1.0, 0.5]},
        **over,
    }
    return ExperimentConfig.model_validate(raw)


#: the module's log: blocks, parts and cells as a big log has them, small enough that a run's
#: fixed costs (Ray Data's planning, the BC tasks' start) are most of its time
N = 1500


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("streamed") / "log.parquet"
    write_styled_log(path, N, d=8, seed=1)
    return path


def run(cfg, out: Path):
    from pcpg_dist.api.run import run_experiment

    return run_experiment(cfg, workdir=out, track=False, show_progress=False)


@pytest.fixture(scope="module")
def streamed(ray_session, log, tmp_path_factory):
    """One streamed run of the module's log (several tests read it)."""
    return run(config(log), tmp_path_factory.mktemp("streamed-run"))


def test_a_streamed_run_finds_the_styles_and_its_agents_beat_no_clustering(streamed, log):
    res = streamed
    (env,) = res.clustering
    assert res.clustering[env]["clustering/accuracy"] >= 0.95
    m = res.metrics
    assert m["pcpg/accuracy/p1"] >= 0.7  # the styles' policies: ~0.81 of actions predictable
    assert m["pcpg/accuracy/p1"] >= m["baseline/accuracy/p1"] + 0.15
    assert m["pcpg/accuracy/p0.5"] >= m["baseline/accuracy/p0.5"] + 0.15
    summary = res.out_dir / "summary"
    record = json.loads((summary / "streamed.json").read_text())
    assert record["n_trajectories"] == N and record["steps"] == pq.read_metadata(log).num_rows
    assert set(record["stage_seconds"]) == {
        "features",
        "cluster",
        "rank",
        "tag",
        "train",
        "evaluate",
    }
    labels = pq.read_table(summary / "labels_seed0.parquet").to_pandas()
    assert sorted(labels.trajectory) == list(range(N))
    assert labels.test.mean() == pytest.approx(0.2, abs=0.03)
    with np.load(summary / "agents_seed0.npz", allow_pickle=False) as agents:
        assert {k.split("_")[0] for k in agents.files} == {
            "cell0",
            "cell1",
            "cell2",
            "cell3",
            "cellnc",
        }
    # p = 0.5 keeps about half of each cluster's training trajectories (bit 10 + 2 of the code)
    train = labels[~labels.test]
    kept = ((train.code.to_numpy() >> 12) & 1).astype(bool)
    assert kept.mean() == pytest.approx(0.5, abs=0.03)


def test_a_minari_dataset_streams_like_the_same_log_in_parquet(
    streamed, log, tmp_path, monkeypatch
):
    """The module's log exported to a local Minari dataset and streamed (episodes read a part at
    a time in the block tasks): the same trajectories and steps, the same clusters, agents as
    good."""
    from pcpg_dist.domains.trajectories.minari_io import write_minari
    from pcpg_dist.domains.trajectories.synthetic_log import styled_dataset

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    ds = styled_dataset(log)
    write_minari({"log": ds}, tmp_path / "minari", "pcpg/styled-v0")
    from pcpg_dist.domains.trajectories import minari_stream

    monkeypatch.setattr(minari_stream, "STEPS_PER_PART", 10_000)  # several parts, as a big log
    res = run(config("minari:pcpg/styled-v0"), tmp_path / "run")
    record = json.loads((res.out_dir / "summary" / "streamed.json").read_text())
    parquet = json.loads((streamed.out_dir / "summary" / "streamed.json").read_text())
    assert (record["n_trajectories"], record["steps"]) == (N, pq.read_metadata(log).num_rows)
    (env,) = res.clustering
    (penv,) = streamed.clustering
    assert res.clustering[env]["clustering/accuracy"] == pytest.approx(
        streamed.clustering[penv]["clustering/accuracy"], abs=0.01
    )
    assert res.clustering[env]["clustering/accuracy"] >= 0.95
    m = res.metrics
    assert m["pcpg/accuracy/p1"] == pytest.approx(parquet["metrics"]["pcpg/accuracy/p1"], abs=0.02)
    assert m["pcpg/accuracy/p1"] >= m["baseline/accuracy/p1"] + 0.15


@pytest.mark.slow  # a streamed run besides the module's
def test_the_same_seed_gives_the_same_numbers_however_the_log_is_cut(
    streamed, log, tmp_path, monkeypatch
):
    """(The same log in one file gives the same numbers twice: the MLflow test's run.)"""
    from pcpg_dist.domains.trajectories import stream_meta

    first = streamed  # the module's run of the same config, in a folder of its own
    # the same trajectories as a folder of 3 files, read in 7 blocks: the same clusters
    folder = tmp_path / "parts"
    folder.mkdir()
    table = pq.read_table(log)
    for i, lo in enumerate(range(0, table.num_rows, -(-table.num_rows // 3))):
        pq.write_table(table.slice(lo, -(-table.num_rows // 3)), folder / f"part-{i}.parquet")
    monkeypatch.setattr(stream_meta, "STEPS_PER_BATCH", table.num_rows // 7)
    cut = run(config(folder), tmp_path / "c")
    a = pq.read_table(first.out_dir / "summary" / "labels_seed0.parquet").to_pandas()
    c = pq.read_table(cut.out_dir / "summary" / "labels_seed0.parquet").to_pandas()
    a, c = a.sort_values("trajectory"), c.sort_values("trajectory")
    assert (a.cluster.to_numpy() == c.cluster.to_numpy()).all()
    assert (a.code.to_numpy() == c.code.to_numpy()).all()
    assert cut.clustering == first.clustering
    assert cut.metrics["pcpg/accuracy/p1"] == pytest.approx(
        first.metrics["pcpg/accuracy/p1"], abs=0.02
    )


def test_auto_streams_only_logs_above_the_size(log):
    rows = pq.read_metadata(log).num_rows
    assert stream_source(config(log, trajectories={"stream": "auto"})) is None
    found = stream_source(
        config(log, trajectories={"stream": "auto", "stream_above_steps": rows - 1})
    )
    assert found.steps == rows and found.n_actions == 4 and len(found.states) == 8
    assert found.optional == ("reward", "style")
    assert (
        stream_source(config(log, trajectories={"stream": "off", "stream_above_steps": 0})) is None
    )


def test_move_features_on_a_streamed_log_are_refused_in_one_line(log):
    streamed = config(log, clustering={"k": 4, "move_features": "tests.move_toy:features"})
    with pytest.raises(DataError, match="clustering.move_features: .* streams") as got:
        stream_source(streamed)
    assert "trajectories.stream: off" in str(got.value) and "\n" not in str(got.value)


def test_a_bad_row_inside_a_block_is_one_line_naming_its_column(ray_session, log, tmp_path):
    table = pq.read_table(log)
    action = table.column("action").to_numpy().copy()
    action[len(action) // 2] = 7
    bad = tmp_path / "bad.parquet"
    pq.write_table(table.set_column(2, "action", pa.array(action)), bad)
    with pytest.raises(
        DataError, match=r"column 'action': trajectory \d+ has action 7; actions are 0..3"
    ):
        run(config(bad, trajectories={"n_actions": 4}), tmp_path / "out")
    assert not (tmp_path / "out" / "streamed" / "summary").exists()


@pytest.mark.parametrize(
    ("change", "says"),
    [
        ({"trajectory": pa.array(["x"] * 5)}, "needs integer trajectory values"),
        ({"s0": pa.array(["a"] * 5)}, "state column 's0' is string"),
    ],
)
def test_a_log_that_cannot_stream_is_refused_from_its_footer(tmp_path, change, says):
    cols = {
        "trajectory": pa.array([0] * 5),
        "t": pa.array(range(5)),
        "action": pa.array([0, 1, 0, 1, -1]),
        "s0": pa.array([0.0] * 5),
    }
    cols.update(change)
    path = tmp_path / "log.parquet"
    pq.write_table(pa.table(cols), path)
    with pytest.raises(DataError, match=says):
        stream_source(config(path))


def test_a_named_score_column_needs_the_in_memory_pipeline(log):
    with pytest.raises(DataError, match="ranks by return, length or -length"):
        stream_source(config(log, trajectories={"score": "skill"}))


def test_a_streamed_run_is_one_mlflow_run_with_its_log_as_input(streamed, log, tmp_path):
    """The module's config again, tracked, in another folder: one MLflow run, and the same
    numbers as the module's run (the same seed, run twice)."""
    from mlflow.tracking import MlflowClient

    from pcpg_dist.api.run import run_experiment

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    res = run_experiment(
        config(log),
        workdir=tmp_path / "runs",
        tracking_uri=uri,
        track=True,
        show_progress=False,
        command="pcpg run streamed.yaml",
    )
    assert res.metrics == streamed.metrics and res.clustering == streamed.clustering
    run = MlflowClient(uri).get_run(res.parent_run_id)
    m = run.data.metrics
    assert m["pcpg/accuracy/p1"] == pytest.approx(res.metrics["pcpg/accuracy/p1"])
    assert m["clustering/accuracy"] >= 0.95 and m["seconds/train"] > 0
    assert run.data.params["clustering.k"] == "4"
    assert run.data.tags["pcpg.streamed"] == "true"
    (data,) = [i for i in run.inputs.dataset_inputs if i.tags[0].value == "training"]
    assert data.dataset.name == "log.parquet" and data.dataset.source_type == "local"
    artifacts = [a.path for a in MlflowClient(uri).list_artifacts(run.info.run_id)]
    assert "streamed.json" in artifacts


@pytest.mark.parametrize(
    ("node_cpus", "cells", "expected"),
    [
        ([2], 5, (1, 2)),  # a laptop: one task, both cores (one torch import, one read an epoch)
        ([0, 2], 5, (1, 2)),  # a head with no CPU of its own and one worker
        ([16], 5, (4, 4)),  # a big node: a few threads a task, enough tasks to fill it
        ([16], 2, (2, 4)),  # never more tasks than cells
        ([2, 8, 8], 10, (9, 2)),  # threads fit the smallest node, so every task fits anywhere
        ([1], 3, (1, 1)),
        ([0], 3, (1, 1)),  # no CPU reported at all: still one task
    ],
)
def test_bc_runs_in_as_few_tasks_as_keep_every_cpu_busy(node_cpus, cells, expected):
    from pcpg_dist.orchestration.streaming.training import bc_tasks

    tasks, threads = bc_tasks(node_cpus, cells)
    assert (tasks, threads) == expected
    assert tasks * threads <= max(sum(node_cpus), 1)


def test_bc_workers_have_exited_when_training_returns(ray_session):
    """Each BC task's worker (torch and its buffers, ~1 GB on a large log) is gone before the
    next step starts workers of its own; the cells still learn their rows."""
    import psutil
    import ray.data

    from pcpg_dist.orchestration.streaming.training import TrainSpec, train_cells
    from pcpg_dist.stages.streamed import cells as P

    rng = np.random.default_rng(0)
    n = 4000
    cluster = rng.integers(0, 2, n)
    x = (rng.normal(size=(n, 3)) + 2.0 * cluster[:, None]).astype(np.float32)
    y = cluster.astype(np.int16)  # each cluster's policy: its own action
    test = rng.random(n) < 0.2
    kept = [np.ones(n, bool)]
    code = P.code_of(cluster, test, rng.random(n) < 0.1, kept, kept)

    def table(rows):  # one block, as the tagging step makes them
        return ray.data.from_items([{"block": 0}]).map_batches(
            lambda _: {"x": x[rows], "y": y[rows], "code": code[rows]}, batch_size=None
        )

    spec = TrainSpec(
        d=3,
        n_actions=2,
        layers=1,
        width=16,
        activation="relu",
        lr=1e-2,
        betas=(0.9, 0.999),
        eps=1e-8,
        batch=256,
        max_epochs=5,
    )
    groups = train_cells(
        table(np.flatnonzero(~test)).materialize(),
        table(np.flatnonzero(test)).materialize(),
        [(0, 0), (1, 0), (P.NC, 0)],
        spec,
        seed=0,
        k=2,
        node_cpus=[2],
    )
    for g in groups:  # gone, or a zombie its raylet has not reaped yet (no memory held)
        with contextlib.suppress(psutil.NoSuchProcess):
            assert psutil.Process(g["worker"][1]).status() == psutil.STATUS_ZOMBIE
    rows = groups[0]["test_rows"]  # held-out rows of each cluster
    assert rows.sum() == test.sum()
    for g in groups:
        for (c, _), correct in zip(g["cells"], g["correct"], strict=True):
            if c == P.NC:  # No Clustering saw both clusters
                assert correct.sum() >= 0.95 * rows.sum()
            else:  # a cluster's cell knows its own cluster's action
                assert correct[c] >= 0.95 * rows[c]


def test_classify_labels_a_log_block_by_block_with_the_runs_clustering(
    streamed, log, tmp_path, capsys
):
    """`pcpg classify RUN/summary/model_seed0 LOG`: the run's own log gets the run's clusters,
    trajectory by trajectory; a fresh log of the same styles is labelled as well; the driver
    holds only the cluster sizes (the labels go to --out batch by batch)."""
    import pandas as pd

    import pcpg_dist
    from pcpg_dist.cli import main

    model = streamed.out_dir / "summary" / "model_seed0"
    out = tmp_path / "labels.csv"
    assert main(["classify", str(model), str(log), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"{N} trajectories -> {out}; cluster sizes [" in printed
    (quality,) = streamed.clustering.values()  # the run's own score of the same labels
    assert f"against the true styles: clustering/accuracy {quality['clustering/accuracy']:.3f}" in (
        printed
    )
    got = pd.read_csv(out).sort_values("trajectory")
    run_labels = pq.read_table(streamed.out_dir / "summary" / "labels_seed0.parquet").to_pandas()
    run_labels = run_labels.sort_values("trajectory")
    assert (got.trajectory.to_numpy() == run_labels.trajectory.to_numpy()).all()
    assert (got.predicted_style.to_numpy() == run_labels.cluster.to_numpy()).all()
    # a fresh log of the same styles (other noise), as Parquet: labelled as well as the first
    fresh = tmp_path / "fresh.parquet"
    write_styled_log(fresh, 600, d=8, seed=7)
    table = pcpg_dist.classify(model, fresh, out=tmp_path / "fresh.styles.parquet")
    assert list(table.columns) == ["predicted_style", "trajectories"]
    assert table.trajectories.sum() == table.attrs["trajectories"] == 600
    assert table.attrs["against_styles"]["clustering/accuracy"] >= 0.95
    written = pq.read_table(tmp_path / "fresh.styles.parquet").to_pandas()
    assert sorted(written.trajectory) == list(range(600))
    assert np.bincount(written.predicted_style, minlength=4).tolist() == table.trajectories.tolist()


@pytest.mark.parametrize(
    ("damage", "says"),
    [
        (lambda m: m["centres"][1].pop(), "centres[1]:"),
        (lambda m: m["scale"].__setitem__(0, 0.0), "scale: every value must be a positive"),
        (lambda m: m.update(n_actions="four"), "n_actions"),
        (lambda m: m.update(extra=1), "extra"),
        (lambda m: m.update(states=["s0", "s1"]), "mean: 21 values; the features need 9"),
    ],
)
def test_a_damaged_streamed_model_is_one_line_naming_the_field(
    streamed, log, tmp_path, capsys, damage, says
):
    import shutil

    from pcpg_dist.cli import main

    model = tmp_path / "model"
    shutil.copytree(streamed.out_dir / "summary" / "model_seed0", model)
    raw = json.loads((model / "streamed_model.json").read_text())
    damage(raw)
    (model / "streamed_model.json").write_text(json.dumps(raw))
    assert main(["classify", str(model), str(log), "--out", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and "streamed_model.json" in err and "\n" not in err, err
    assert not (tmp_path / "o.csv").exists()


def test_a_log_of_other_columns_is_refused_in_one_line(streamed, tmp_path, capsys):
    from pcpg_dist.cli import main

    other = tmp_path / "other.parquet"
    write_styled_log(other, 200, d=6, seed=3)
    model = streamed.out_dir / "summary" / "model_seed0"
    assert main(["classify", str(model), str(other), "--out", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert "state columns s0..s5 (6)" in err and "s0..s7 (8)" in err and "\n" not in err, err
