"""MLflow layout for review, idempotent reruns, the store under concurrent use, sweep runs.

The run results are the GridWorld reference metrics (tests/reference/metrics.json: a real run's
summary: environment E2, ps 1 and 0.5, corruption levels 0 and 1), so the layout is checked on
what a run really logs; no Ray and no training here.
"""

from __future__ import annotations

import contextlib
import json
import os
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from pcpg_dist.common.errors import ServiceError
from pcpg_dist.common.point_labels import point_label, short_keys
from pcpg_dist.config import load_config
from pcpg_dist.orchestration.points import RunResult
from pcpg_dist.tracking.children import log_environment
from pcpg_dist.tracking.runs import (
    find_run,
    open_experiment,
    sweep_points_of,
)
from pcpg_dist.tracking.tags import EXPERIMENT_KIND, MAX_PARENT_METRICS
from pcpg_dist.tracking.trackers import SweepTracker, Tracker

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = json.loads((ROOT / "tests" / "reference" / "metrics.json").read_text())["gridworld"]
ENVS = sorted({k.split("/")[0] for k in REFERENCE if k.startswith("E")})


def make_result(out: Path) -> RunResult:
    summary = out / "summary"
    (summary / "E1").mkdir(parents=True, exist_ok=True)
    (summary / "metrics.json").write_text(json.dumps(REFERENCE))
    (summary / "run.json").write_text(json.dumps({"command": "pcpg run experiments/quick.yaml"}))
    (summary / "accuracy_vs_p.csv").write_text("env,p,pcpg\nE1,1.0,0.8\n")
    (summary / "E1" / "done.json").write_text("{}")  # cache bookkeeping: must not be uploaded
    (summary / "E1" / "table.csv").write_text("a\n1\n")
    (out / "report").mkdir(exist_ok=True)
    (out / "report" / "report.html").write_text("<html></html>")
    clustering = {
        e: {k.split("/", 1)[1]: v for k, v in REFERENCE.items() if k.startswith(f"{e}/clustering/")}
        for e in ENVS
    }
    return RunResult(
        out,
        dict(REFERENCE),
        clustering,
        {"generate": 1.5, "cluster": 2.0, "train": 3.0, "evaluate": 1.0, "summary": 0.5},
    )


def env_metrics(env: str) -> dict[str, float]:
    return {k.split("/", 1)[1]: v for k, v in REFERENCE.items() if k.startswith(f"{env}/")}


def run_once(cfg, uri: str, out: Path, summary_seconds: float = 0.5) -> Tracker:
    """What `pcpg run` does with tracking, for one finished run (children, then the parent)."""
    result = make_result(out)
    result.stage_seconds["summary"] = summary_seconds  # recomputed by every run, so it varies
    tracker = Tracker.start(cfg, uri, out)
    evaluation = out / "eval"
    evaluation.mkdir(exist_ok=True)
    (evaluation / "metrics.json").write_text("{}")
    (evaluation / "done.json").write_text("{}")
    for env in ENVS:
        if not tracker.env_logged(env, f"key-{env}"):
            log_environment(
                tracker.child_info(env, f"key-{env}", result.clustering[env]),
                env,
                str(evaluation),
                env_metrics(env),
                [],
            )
    tracker.finish(result, report_dir=out / "report")
    return tracker


@pytest.fixture(scope="module")
def cfg():
    return load_config(ROOT / "experiments" / "quick.yaml")


def all_artifacts(client, run_id: str, path: str | None = None) -> list[str]:
    out = []
    for a in client.list_artifacts(run_id, path):
        out += all_artifacts(client, run_id, a.path) if a.is_dir else [a.path]
    return out


def histories(client, run) -> dict[str, list]:
    return {k: client.get_metric_history(run.info.run_id, k) for k in run.data.metrics}


def test_parent_layout_for_review(cfg, tmp_path):
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    tracker = run_once(cfg, uri, tmp_path / "out")
    client = MlflowClient(uri)
    exp = client.get_experiment(tracker.experiment_id)
    assert exp.tags[EXPERIMENT_KIND[0]] == "custom_model_development"  # opens on the runs table
    parent = client.get_run(tracker.parent_id)
    keys = set(parent.data.metrics)
    assert len(keys) <= MAX_PARENT_METRICS, sorted(keys)
    assert not any(
        k.endswith("/std") or k.startswith(tuple(f"{e}/" for e in ENVS)) for k in keys
    ), sorted(keys)
    # the headline numbers are the run's, not placeholders
    for key in (
        "pcpg/accuracy/p1",
        "baseline/accuracy/p1",
        "clustering/accuracy",
        "random/accuracy",
    ):
        assert parent.data.metrics[key] == pytest.approx(REFERENCE[key]), key
    # accuracy over p as a curve: one point per p, step = 100 p, values in p order
    curve = client.get_metric_history(tracker.parent_id, "accuracy_vs_p/pcpg")
    assert sorted((m.step, m.value) for m in curve) == [
        (50, pytest.approx(REFERENCE["pcpg/accuracy/p0.5"])),
        (100, pytest.approx(REFERENCE["pcpg/accuracy/p1"])),
    ]
    corruption = client.get_metric_history(tracker.parent_id, "accuracy_vs_corruption/pcpg")
    assert sorted(m.step for m in corruption) == [0, 100]
    note = parent.data.tags["mlflow.note.content"]
    assert (
        "pcpg run experiments/quick.yaml" in note and f"{REFERENCE['pcpg/accuracy/p1']:.3f}" in note
    )
    # the result opens the description (the runs table's Description column shows its start)
    assert note.startswith(
        f"PCPG vs No Clustering accuracy: {REFERENCE['pcpg/accuracy/p1']:.3f} vs "
        f"{REFERENCE['baseline/accuracy/p1']:.3f} at p = 1; "
    ), note
    assert parent.info.status == "FINISHED"
    files = all_artifacts(client, tracker.parent_id)
    assert "summary/accuracy_vs_p.csv" in files and "report/report.html" in files
    assert not any(Path(f).name == "done.json" for f in files), files
    std = client.download_artifacts(tracker.parent_id, "summary/metrics.csv", str(tmp_path / "dl"))
    rows = {r.split(",")[0]: r.split(",") for r in Path(std).read_text().splitlines()[1:]}
    assert float(rows["pcpg/accuracy/p1"][2]) == pytest.approx(REFERENCE["pcpg/accuracy/p1/std"])
    # children: per-environment detail, curves by p, no std sections, no bookkeeping files
    children = client.search_runs(
        [tracker.experiment_id], f"tags.`mlflow.parentRunId` = '{tracker.parent_id}'"
    )
    assert sorted(c.data.tags["pcpg.env"] for c in children) == ENVS
    for child in children:
        cm = child.data.metrics
        assert not any(k.endswith("/std") for k in cm)
        assert "pcpg/accuracy/k0/by_p" in cm and "clustering/ari" in cm
        assert all(Path(f).name != "done.json" for f in all_artifacts(client, child.info.run_id))


def test_rerun_from_cache_logs_nothing_again(cfg, tmp_path):
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    first = run_once(cfg, uri, tmp_path / "out")
    client = MlflowClient(uri)
    before = client.get_run(first.parent_id)
    hist_before = histories(client, before)
    for i in range(2):
        again = run_once(cfg, uri, tmp_path / "out", summary_seconds=0.7 + i)
        assert again.parent_id == first.parent_id
    after = client.get_run(first.parent_id)
    assert (after.info.start_time, after.info.end_time) == (
        before.info.start_time,
        before.info.end_time,
    )
    assert after.data.metrics == before.data.metrics
    for key, hist in histories(client, after).items():
        steps = [m.step for m in hist]
        assert len(steps) == len(set(steps)) == len(hist_before[key]), (
            key
        )  # one value per step, ever
        if not key.startswith("accuracy_vs_"):
            assert len(hist) == 1, key
    runs = client.search_runs([first.experiment_id])
    assert len(runs) == 1 + len(ENVS) and all(r.info.status == "FINISHED" for r in runs)


def test_killed_parent_resumes_and_is_finished_once(cfg, tmp_path):
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    tracker = Tracker.start(cfg, uri, tmp_path / "out")
    tracker.fail()
    client = MlflowClient(uri)
    assert client.get_run(tracker.parent_id).info.status == "KILLED"
    resumed = run_once(cfg, uri, tmp_path / "out")
    assert resumed.parent_id == tracker.parent_id
    assert client.get_run(tracker.parent_id).info.status == "FINISHED"


@pytest.mark.parametrize(
    "where",
    [
        "pcpg_dist.tracking.runs._log_params",
        "pcpg_dist.tracking.trackers.data_inputs",
        "pcpg_dist.tracking.trackers.log_data_inputs",
    ],
)
def test_sigterm_while_the_parent_is_being_made_marks_it_killed(cfg, tmp_path, monkeypatch, where):
    """SIGTERM between the parent's creation and Tracker.start's return (its params or data inputs
    being logged: seconds on a loaded store) left it RUNNING: the caller's cleanup had no tracker
    yet to mark (CI, test_sigterm_is_one_line_exit_143_and_marks_the_mlflow_run_killed)."""
    from mlflow import MlflowClient

    from pcpg_dist.common.errors import Terminated

    def interrupted(*args, **kwargs):
        raise Terminated()

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setattr(where, interrupted)
    with pytest.raises(Terminated):
        Tracker.start(cfg, uri, tmp_path / "out", ikey="data-key", units=[])
    client = MlflowClient(uri)
    runs = client.search_runs([e.experiment_id for e in client.search_experiments()])
    assert [r.info.status for r in runs] == ["KILLED"]


CONCURRENT = textwrap.dedent("""
    import sys
    from pathlib import Path
    sys.path.insert(0, {tests!r})
    from test_tracking import run_once
    from pcpg_dist.config import load_config
    cfg = load_config({config!r})
    run_once(cfg, {uri!r}, Path(sys.argv[1]))
""")


@pytest.mark.slow
def test_two_processes_on_one_store_make_one_parent(cfg, tmp_path):
    """Two `pcpg run`s of one config started together: on a fresh folder, then on the existing store."""
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path / 'store' / 'mlflow.db'}"
    script = tmp_path / "one_run.py"
    script.write_text(
        CONCURRENT.format(
            tests=str(ROOT / "tests" / "tracking"),
            config=str(ROOT / "experiments" / "quick.yaml"),
            uri=uri,
        )
    )
    for round_ in ("fresh", "existing"):
        procs = [
            subprocess.Popen(
                [sys.executable, str(script), str(tmp_path / f"{round_}{i}")],
                text=True,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
            )
            for i in range(2)
        ]
        outs = [p.communicate(timeout=600)[0] for p in procs]
        assert [p.returncode for p in procs] == [0, 0], outs
        client = MlflowClient(uri)
        exp = client.get_experiment_by_name(cfg.name)
        runs = client.search_runs([exp.experiment_id])
        parents = [r for r in runs if r.data.tags.get("pcpg.role") == "parent"]
        assert len(parents) == 1, (round_, [r.info.run_id for r in parents])
        children = [
            r for r in runs if r.data.tags.get("mlflow.parentRunId") == parents[0].info.run_id
        ]
        assert sorted(c.data.tags["pcpg.env"] for c in children) == ENVS, round_
        assert all(r.info.status == "FINISHED" for r in runs)
        assert all(len(h) == 1 for k, h in histories(client, parents[0]).items() if "_vs_" not in k)


def _partial_store(db: Path, revisions_done: int) -> None:
    """A store as a migration killed after ``revisions_done`` steps leaves it (one step's tables
    created, its version not yet recorded: SQLite runs DDL outside the migration's transaction)."""
    from alembic import command
    from alembic.script import ScriptDirectory
    from mlflow.store.db.utils import InitialBase, _get_alembic_config, create_sqlalchemy_engine

    uri = f"sqlite:///{db}"
    engine = create_sqlalchemy_engine(uri)
    InitialBase.metadata.create_all(engine)
    config = _get_alembic_config(uri)
    revisions = list(reversed(list(ScriptDirectory.from_config(config).walk_revisions())))
    with engine.begin() as connection:
        config.attributes["connection"] = connection
        command.upgrade(config, revisions[revisions_done].revision)
    engine.dispose()
    con = sqlite3.connect(db)
    con.execute(
        "UPDATE alembic_version SET version_num = ?", (revisions[revisions_done - 1].revision,)
    )
    con.commit()
    con.close()


def test_half_created_store_is_repaired(cfg, tmp_path, caplog):
    from mlflow import MlflowClient
    from mlflow.store.tracking.sqlalchemy_store import SqlAlchemyStore
    from sqlalchemy.exc import OperationalError

    db = tmp_path / "mlflow.db"
    _partial_store(db, 5)
    uri = f"sqlite:///{db}"
    with pytest.raises(OperationalError):  # MLflow alone cannot open it again
        SqlAlchemyStore(uri, (tmp_path / "mlruns").as_uri())
    with caplog.at_level("WARNING", logger="pcpg_dist.tracking"):
        tracker = run_once(cfg, uri, tmp_path / "out")
    assert MlflowClient(uri).get_run(tracker.parent_id).info.status == "FINISHED"
    moved = list(tmp_path.glob("mlflow.db.incomplete-*"))
    assert len(moved) == 1
    # pcpg's own records only: _partial_store ran MLflow's migration itself, whose INFO lines are
    # captured when an earlier test left MLflow's loggers at INFO
    lines = [r.getMessage() for r in caplog.records if r.name == "pcpg_dist.tracking"]
    assert len(lines) == 1 and "half-created" in lines[0] and "\n" not in lines[0]


@pytest.mark.slow
def test_store_whose_first_migration_was_killed_opens(cfg, tmp_path):
    """kill -9 while MLflow creates a fresh store (as a run stopped during its first seconds would):
    the next run repairs it or finds it whole, and logs."""
    import os
    import signal
    import time

    from mlflow import MlflowClient

    db = tmp_path / "mlflow.db"
    uri = f"sqlite:///{db}"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"from mlflow import MlflowClient; MlflowClient({uri!r}).search_experiments()",
        ],
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 120
    while (
        not (db.exists() and db.stat().st_size > 0)
        and proc.poll() is None
        and time.monotonic() < deadline
    ):
        time.sleep(0.02)
    time.sleep(0.3)  # inside the migration's dozens of steps
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    tracker = run_once(cfg, uri, tmp_path / "out")
    assert MlflowClient(uri).get_run(tracker.parent_id).info.status == "FINISHED"


def test_damaged_store_with_runs_is_one_line(cfg, tmp_path):
    db = tmp_path / "mlflow.db"
    uri = f"sqlite:///{db}"
    open_experiment("kept", uri)
    from mlflow import MlflowClient

    MlflowClient(uri).create_run(MlflowClient(uri).get_experiment_by_name("kept").experiment_id)
    con = sqlite3.connect(db)
    con.execute("UPDATE alembic_version SET version_num = 'not_a_revision'")
    con.commit()
    con.close()
    from pcpg_dist.tracking import store

    store._prepared.discard(uri)  # a new process would check again
    with pytest.raises(ServiceError) as err:
        store.prepare_store(uri)
    msg = str(err.value)
    assert "\n" not in msg and str(db) in msg and "1 runs" in msg
    assert list(tmp_path.glob("mlflow.db.backup-*"))


def test_sweep_run_is_found_again_and_points_nest_under_it(cfg, tmp_path):
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    axes = {"bc.lr": [0.01, 0.001], "clustering.k": [2, 4]}
    sweep = SweepTracker.start("quick-sweep", "abc123", axes, "lr x k on quick", uri)
    again = SweepTracker.start("quick-sweep", "abc123", axes, "lr x k on quick", uri)
    assert again.parent_id == sweep.parent_id
    other = SweepTracker.start("quick-sweep", "def456", axes, "another grid", uri)
    assert other.parent_id != sweep.parent_id
    client = MlflowClient(uri)
    run = client.get_run(sweep.parent_id)
    assert (
        run.data.params["sweep.bc.lr"] == "0.01,0.001"
        and run.data.tags["mlflow.note.content"] == "lr x k on quick"
    )

    point = Tracker.start(
        cfg, uri, tmp_path / "p0", parent_run_id=sweep.parent_id, params={"bc.lr": "0.01"}
    )
    assert (
        Tracker.start(
            cfg, uri, tmp_path / "p0", parent_run_id=sweep.parent_id, params={"bc.lr": "0.01"}
        ).parent_id
        == point.parent_id
    )
    solo = Tracker.start(
        cfg, uri, tmp_path / "solo"
    )  # the same config outside the sweep: its own run
    assert solo.parent_id != point.parent_id
    prun = client.get_run(point.parent_id)
    assert (
        prun.data.tags["mlflow.parentRunId"] == sweep.parent_id
        and prun.data.params["bc.lr"] == "0.01"
    )
    assert prun.info.experiment_id == sweep.experiment_id

    artifact = tmp_path / "summary.csv"
    artifact.write_text("bc.lr,pcpg\n0.01,0.8\n")
    for _ in range(2):
        sweep.finish({"best/pcpg_accuracy": 0.8}, [artifact])
    run = client.get_run(sweep.parent_id)
    assert run.info.status == "FINISHED"
    assert len(client.get_metric_history(sweep.parent_id, "best/pcpg_accuracy")) == 1
    assert [a.path for a in client.list_artifacts(sweep.parent_id)] == ["summary.csv"]
    other.fail()
    assert client.get_run(other.parent_id).info.status == "KILLED"


def test_an_experiment_name_is_its_newest_top_level_run_never_a_sweeps_point(cfg, tmp_path):
    """`pcpg report quick` / `reproduce` / `export onnx`: the newest `pcpg run` or `pcpg sweep` of the
    experiment; a sweep's points (role parent, under the sweep run) were picked as the newest."""
    import time

    from mlflow import MlflowClient

    from pcpg_dist.config import parse_config

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    solo = Tracker.start(cfg, uri, tmp_path / "solo")
    assert find_run(cfg.name, uri)[0].info.run_id == solo.parent_id
    time.sleep(0.01)
    sweep = SweepTracker.start(cfg.name, "key1", {"bc.lr": [0.01, 0.001]}, "lr on quick", uri)
    time.sleep(0.01)
    point = Tracker.start(
        cfg, uri, tmp_path / "p0", parent_run_id=sweep.parent_id, params={"bc.lr": "0.01"}
    )
    client = MlflowClient(uri)
    assert (
        client.get_run(point.parent_id).info.start_time
        > client.get_run(sweep.parent_id).info.start_time
    )
    run, found_at = find_run(cfg.name, uri)
    assert run.info.run_id == sweep.parent_id and found_at == uri
    time.sleep(0.01)
    other = parse_config(
        {**cfg.model_dump(mode="json"), "seed": cfg.seed + 1}, source="quick, seed + 1"
    )
    newer = Tracker.start(other, uri, tmp_path / "newer")
    assert find_run(cfg.name, uri)[0].info.run_id == newer.parent_id
    assert find_run(point.parent_id, uri)[0].info.run_id == point.parent_id  # a run id is that run
    with pytest.raises(ServiceError, match="has no pcpg run or sweep yet"):
        client.create_experiment("empty")
        find_run("empty", uri)


def test_short_keys_use_the_last_segment_unless_ambiguous():
    assert short_keys(["pbtg.noise_max", "clustering.k"]) == {
        "pbtg.noise_max": "noise_max",
        "clustering.k": "k",
    }
    assert short_keys(["clustering.k", "pbtg.k", "bc.lr"]) == {
        "clustering.k": "clustering.k",
        "pbtg.k": "pbtg.k",
        "bc.lr": "lr",
    }
    assert point_label({"pbtg.noise_max": "0.3", "clustering.k": "4"}) == "noise_max=0.3 k=4"


def test_sweep_points_and_their_environments_are_named_by_their_axis_values(cfg, tmp_path):
    """Every point was named "<name>-<hash> [pbtg.noise_max=0.3 clustering.k=4]" (cut off in the UI
    before the values) and every point's environments "E1", "E2"; points were role "parent" like a
    `pcpg run`. Runs are found by tags: a rerun reuses every run, and an older pcpg's point (role
    "parent", the old name) is found, retagged and renamed, never duplicated."""
    from mlflow import MlflowClient

    from pcpg_dist.config import parse_config

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    axes = {"pbtg.noise_max": [0.1, 0.3], "clustering.k": [3, 4]}
    sweep = SweepTracker.start(cfg.name, "key", axes, "noise x k", uri)
    client = MlflowClient(uri)
    assert client.get_run(sweep.parent_id).info.run_name.startswith(
        "sweep noise_max x k (4 points)"
    )
    raw = cfg.model_dump(mode="json")

    def points() -> dict[str, str]:
        ids = {}
        for noise in axes["pbtg.noise_max"]:
            for k in axes["clustering.k"]:
                point_cfg = parse_config(
                    {
                        **raw,
                        "pbtg": {**raw["pbtg"], "noise_max": noise},
                        "clustering": {**raw["clustering"], "k": k},
                    },
                    source="point",
                )
                params = {"pbtg.noise_max": str(noise), "clustering.k": str(k)}
                tracker = Tracker.start(
                    point_cfg,
                    uri,
                    tmp_path / f"{noise}-{k}",
                    parent_run_id=sweep.parent_id,
                    params=params,
                )
                out = tmp_path / "eval"
                out.mkdir(exist_ok=True)
                for env in ENVS:
                    log_environment(
                        tracker.child_info(env, f"key-{env}", {}),
                        env,
                        str(out),
                        env_metrics(env),
                        [],
                    )
                ids[tracker.label] = tracker.parent_id
        return ids

    first = points()
    assert sorted(first) == [
        "noise_max=0.1 k=3",
        "noise_max=0.1 k=4",
        "noise_max=0.3 k=3",
        "noise_max=0.3 k=4",
    ]
    runs = client.search_runs([sweep.experiment_id], max_results=1000)
    for label, run_id in first.items():
        run = client.get_run(run_id)
        assert run.info.run_name == label and run.data.tags["pcpg.role"] == "point"
        envs = sorted(
            r.info.run_name for r in runs if r.data.tags.get("mlflow.parentRunId") == run_id
        )
        assert envs == [f"{env} · {label}" for env in ENVS]
    assert [r.info.run_id for r in sweep_points_of(sweep.parent_id, uri)] == sorted(
        first.values(), key=lambda i: (client.get_run(i).info.start_time, i)
    )
    assert find_run(cfg.name, uri)[0].info.run_id == sweep.parent_id  # never a point
    assert points() == first  # a rerun reuses every run
    assert len(client.search_runs([sweep.experiment_id], max_results=1000)) == len(runs)

    # a point made by an older pcpg: role "parent", the long name; it is found again, not duplicated
    old_id = first["noise_max=0.3 k=4"]
    client.set_tag(old_id, "pcpg.role", "parent")
    client.set_tag(old_id, "mlflow.runName", "quick-6664d508 [pbtg.noise_max=0.3 clustering.k=4]")
    for child in client.search_runs(
        [sweep.experiment_id], f"tags.`mlflow.parentRunId` = '{old_id}'"
    ):
        client.set_tag(child.info.run_id, "mlflow.runName", child.data.tags["pcpg.env"])
    assert points() == first
    old = client.get_run(old_id)
    assert old.data.tags["pcpg.role"] == "point" and old.info.run_name == "noise_max=0.3 k=4"
    children = client.search_runs([sweep.experiment_id], f"tags.`mlflow.parentRunId` = '{old_id}'")
    assert sorted(c.info.run_name for c in children) == [
        f"{env} · noise_max=0.3 k=4" for env in ENVS
    ]
    assert len(client.search_runs([sweep.experiment_id], max_results=1000)) == len(runs)


def test_parent_budget_keeps_every_p_and_the_clustering_trio_and_drops_duplicates(tmp_path):
    """quick.yaml's parent (ps 1, 0.5, 0.1) logged `pcpg/accuracy/p0.1` but not `baseline/accuracy/p0.1`
    (the budget had gone to `corruption/baseline/accuracy`, equal to `baseline/accuracy/p1`, and to
    timings); a sweep's point logged the whole sweep's stage times as its own."""
    from pcpg_dist.tracking.logged import parent_metrics

    result = make_result(tmp_path)
    m = result.metrics
    for p, shift in (("0.25", 0.01), ("0.1", 0.02)):
        for method in ("pcpg", "baseline", "majority", "random"):
            m[f"{method}/accuracy/p{p}"] = m[f"{method}/accuracy/p0.5"] - shift
    m.update(
        {
            "clustering/ceiling": 0.9,
            "clustering/gap_to_ceiling": 0.9 - m["clustering/accuracy"],
            "reward_distance/style2": 0.0,
            "corruption/accuracy/c0.5": 0.7,
        }
    )
    assert m["corruption/baseline/accuracy"] == m["baseline/accuracy/p1"]
    result.stage_seconds["tracking"] = 0.3
    points, _ = parent_metrics(result)
    keys = {k for k, _, _ in points}
    assert len(keys) <= MAX_PARENT_METRICS, sorted(keys)
    for p in ("1", "0.5", "0.25", "0.1"):
        assert {f"pcpg/accuracy/p{p}", f"baseline/accuracy/p{p}"} <= keys, p
    assert {"clustering/accuracy", "clustering/ceiling", "clustering/gap_to_ceiling"} <= keys
    assert "corruption/baseline/accuracy" not in keys  # == baseline/accuracy/p1, logged already
    assert "majority/accuracy" not in keys  # == the last point of accuracy_vs_p/majority_class
    assert "random/accuracy" in keys and "time/train_seconds" in keys
    m["corruption/baseline/accuracy"] -= 0.01  # a corruption study over other p: its own number
    assert "corruption/baseline/accuracy" in {k for k, _, _ in parent_metrics(result)[0]}
    assert not any(k.startswith("time/") for k, _, _ in parent_metrics(result, timings=False)[0])


def test_a_sweep_point_logs_no_stage_times_and_the_sweep_names_its_best_points(cfg, tmp_path):
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    sweep = SweepTracker.start(cfg.name, "key", {"bc.lr": [0.01, 0.001]}, "lr on quick", uri)
    point = Tracker.start(
        cfg, uri, tmp_path / "p0", parent_run_id=sweep.parent_id, params={"bc.lr": "0.01"}
    )
    point.finish(make_result(tmp_path / "p0"))
    client = MlflowClient(uri)
    metrics = client.get_run(point.parent_id).data.metrics
    assert "pcpg/accuracy/p1" in metrics and not any(k.startswith("time/") for k in metrics), (
        sorted(metrics)
    )
    for i in range(2):  # the rerun's timings differ, yet nothing is logged again
        sweep.finish(
            {"best/pcpg/accuracy/p1": 0.8},
            [],
            best_points={"pcpg/accuracy/p1": "lr=0.01"},
            timings={"time/train_seconds": 3.0 + i},
            note="lr on quick\n\nBest points: …",
        )
    run = client.get_run(sweep.parent_id)
    assert run.data.tags["pcpg.best_point/pcpg/accuracy/p1"] == "lr=0.01"
    assert run.data.tags["mlflow.note.content"].endswith("Best points: …")
    assert [m.value for m in client.get_metric_history(sweep.parent_id, "time/train_seconds")] == [
        3.0
    ]
    assert (
        run.data.tags["pcpg.role"] == "sweep"
        and client.get_run(point.parent_id).data.tags["pcpg.role"] == "point"
    )


# --------------------------------------------------------------------------- the terminal
def test_version_flag_and_global_quiet_verbose():
    import pcpg_dist
    from pcpg_dist.cli import build_parser

    res = subprocess.run(
        [sys.executable, "-m", "pcpg_dist.cli", "--version"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert (
        res.returncode == 0
        and res.stdout.strip() == f"pcpg {pcpg_dist.__version__}"
        and not res.stderr
    )
    args = build_parser().parse_args(["-q", "domains"])
    assert args.global_quiet and not args.verbose
    assert build_parser().parse_args(["--verbose", "domains"]).verbose


def test_written_files_follow_the_umask(tmp_path):
    """atomic_write_bytes (every table, manifest and run.json) no longer leaves 0600 files."""
    import os

    from pcpg_dist.common.files import FILE_MODE, atomic_write_bytes

    atomic_write_bytes(tmp_path / "x.json", b"{}")
    mask = os.umask(0o022)
    os.umask(mask)
    assert (tmp_path / "x.json").stat().st_mode & 0o777 == FILE_MODE == 0o666 & ~mask


@pytest.fixture
def logging_restored(monkeypatch):
    """setup_output changes process-wide logging: put it back for the other tests (caplog)."""
    import logging

    monkeypatch.delenv("MLFLOW_LOGGING_LEVEL", raising=False)
    pcpg = logging.getLogger("pcpg_dist")
    for attr in ("handlers", "propagate", "level"):
        monkeypatch.setattr(pcpg, attr, getattr(pcpg, attr))
    for name in ("mlflow", "alembic"):
        monkeypatch.setattr(logging.getLogger(name), "level", logging.getLogger(name).level)


def test_setup_output_silences_library_chatter(monkeypatch, logging_restored):
    import logging

    from pcpg_dist.common.progress import setup_output

    monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    setup_output()
    import os

    assert (
        os.environ["MLFLOW_LOGGING_LEVEL"] == "WARNING" and os.environ["RAY_AUTH_MODE"] == "token"
    )
    auth = logging.getLogger("ray._private.authentication.authentication_token_setup")
    notice = logging.LogRecord(
        auth.name,
        logging.WARNING,
        __file__,
        1,
        "Token authentication is enabled for "
        "this Ray cluster. Set RAY_AUTH_MODE=disabled to opt out.",
        None,
        None,
    )
    security = logging.LogRecord(
        auth.name,
        logging.WARNING,
        __file__,
        1,
        "Token authentication is disabled for this Ray cluster.",
        None,
        None,
    )
    assert not auth.filter(notice) and auth.filter(security)  # the security warning stays
    worker = logging.getLogger("ray._private.worker")
    monkeypatch.setattr(worker, "filters", list(worker.filters))
    setup_output()
    sigterm = logging.LogRecord(
        worker.name,
        logging.WARNING,
        __file__,
        1,
        "SIGTERM handler is not set because current thread is not the main thread.",
        None,
        None,
    )
    assert not worker.filter(sigterm)  # ray:// connects from a thread: Ray's line is noise
    assert (
        len([f for f in auth.filters if type(f).__name__ == "_DropMessage"]) == 1
    )  # not added twice


def test_a_driver_joining_a_cluster_uses_token_mode_where_a_token_is_at_hand(
    monkeypatch, tmp_path, logging_restored
):
    """Joining a services.sh head (token auth) with RAY_AUTH_MODE unset failed: ray.init, unlike
    `ray start`, does not read the token file by itself."""
    import os

    from pcpg_dist.common.progress import setup_output

    token = tmp_path / "auth_token"
    for present, mode in ((False, None), (True, "token")):
        monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
        monkeypatch.delenv("RAY_AUTH_TOKEN", raising=False)
        monkeypatch.setenv("RAY_AUTH_TOKEN_PATH", str(token))
        if present:
            token.write_text("0" * 64)
        setup_output(private_ray=False)
        assert os.environ.get("RAY_AUTH_MODE") == mode
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")  # a cluster that says so keeps its mode
    setup_output(private_ray=False)
    assert os.environ["RAY_AUTH_MODE"] == "disabled"


def test_a_tracking_uri_pcpg_cannot_use_is_one_line_and_nothing_of_the_users_is_touched(
    tmp_path, capsys
):
    """A sqlite:/// path naming a text file, a folder or another program's database used to be
    'repaired' (moved aside, exit 0); other schemes failed after the data was generated, in 50-170
    lines of traceback. Now each is one line before anything starts, and the files are as they were."""
    from pcpg_dist.cli import main

    notes, folder, app = tmp_path / "notes.txt", tmp_path / "data", tmp_path / "app.db"
    notes.write_text("my notes\n")
    (folder / "kept.txt").parent.mkdir()
    (folder / "kept.txt").write_text("kept\n")
    con = sqlite3.connect(app)
    con.execute("CREATE TABLE runs (id INTEGER, note TEXT)")
    con.execute("INSERT INTO runs VALUES (1, 'precious')")
    con.commit()
    con.close()
    app_bytes = app.read_bytes()
    cases = {
        f"sqlite:///{notes}": "is not an SQLite database",
        f"sqlite:///{folder}": "is not a regular file",
        f"sqlite:///{app}": "table 'runs' is not MLflow's",
        "foo://x": "MLflow stores runs at no foo://",
        str(tmp_path / "nodir" / "mlruns"): "folder store",
        "postgresql://u@127.0.0.1:1/db": "write postgresql+psycopg2://",
        "postgresql+psycopg2://u:secret@127.0.0.1:1/db": "is unreachable",
        # the probe's round: a database or user that does not exist (1 min 50 s of retries,
        # then ~100 lines), a driver pcpg does not ship, HOST:PORT without http:// (read
        # as a folder store), a port that answers but not in HTTP (a 40-line traceback)
        "postgresql+psycopg2://postgres@127.0.0.1:5432/pcpg_no_such_db": 'database "pcpg_no_such_db" does not exist',
        "postgresql+psycopg2://pcpg_no_such_user@127.0.0.1:5432/test": 'role "pcpg_no_such_user" does not exist',
        "postgresql+psycopg://postgres@127.0.0.1:5432/test": "its driver is not installed",
        "127.0.0.1:5000": "has no scheme: write http://127.0.0.1:5000",
        _binary_server(): "does not answer in HTTP",
    }
    for uri, says in cases.items():
        work = tmp_path / "runs"
        assert (
            main(
                [
                    "run",
                    str(ROOT / "experiments" / "quick.yaml"),
                    "--tracking-uri",
                    uri,
                    "--workdir",
                    str(work),
                ]
            )
            == 2
        )
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("pcpg: error:") and says in err[0], (uri, err)
        assert "secret" not in err[0] and not work.exists()
    assert notes.read_text() == "my notes\n" and (folder / "kept.txt").read_text() == "kept\n"
    assert app.read_bytes() == app_bytes and sorted(p.name for p in tmp_path.iterdir()) == [
        "app.db",
        "data",
        "notes.txt",
    ]


def _binary_server() -> str:
    """The URI of a port that answers every connection with bytes that are not HTTP (as Ray's does)."""
    import socket
    import threading

    sock = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        with contextlib.suppress(OSError):
            while True:
                conn = sock.accept()[0]
                conn.recv(65536)  # the request, then an answer that is not HTTP
                conn.sendall(b"\x00\x00\x18\x04\x00\x00\x00\x00\x00\r\n\r\n")
                conn.shutdown(socket.SHUT_RDWR)
                conn.close()

    threading.Thread(target=serve, daemon=True).start()
    return f"http://127.0.0.1:{sock.getsockname()[1]}"


def test_a_failed_calls_reason_is_its_os_error_not_urllib3s_paragraph():
    from pcpg_dist.tracking.connection import _reason

    text = (
        "API request to endpoint /api/2.0/mlflow/runs/get failed with exception HTTPConnectionPool(host="
        "'127.0.0.1', port=18500): Max retries exceeded with url: /api/2.0/mlflow/runs/get?run_id=abc "
        "(Caused by NewConnectionError('<urllib3.connection.HTTPConnection object at 0x7f>: Failed to "
        "establish a new connection: [Errno 111] Connection refused'))"
    )
    assert _reason(OSError(text)) == "[Errno 111] Connection refused"
    long = "word " * 100
    assert _reason(OSError(long)).endswith(" …") and len(_reason(OSError(long))) <= 202


class _Silent:
    """A TCP server that accepts connections and never answers them (a hung tracking server)."""

    def __init__(self) -> None:
        import socket
        import threading

        self.sock = socket.create_server(("127.0.0.1", 0))
        self.uri = f"http://127.0.0.1:{self.sock.getsockname()[1]}"
        self.held: list = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        with contextlib.suppress(OSError):
            while True:
                self.held.append(self.sock.accept()[0])

    def close(self) -> None:
        for conn in self.held:
            conn.close()
        self.sock.close()


class _Counting:
    """An MLflow client call that counts how often pcpg made it."""

    def __init__(self, uri: str) -> None:
        from mlflow import MlflowClient

        self.client, self.tracking_uri, self.calls = MlflowClient(uri), uri, 0

    def get_experiment_by_name(self, name: str):
        self.calls += 1
        return self.client.get_experiment_by_name(name)


def test_a_server_that_hangs_is_reported_after_one_call_not_five(monkeypatch):
    """A server that takes connections and never answers cost every call MLflow's timeout x its
    tries, five times over (~30 min at the defaults); now one call and a /health probe."""
    from pcpg_dist.tracking import connection

    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_TIMEOUT", "1")
    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR", "0")
    monkeypatch.setattr(connection, "HEALTH_TIMEOUT", 1.0)
    server = _Silent()
    try:
        client = _Counting(server.uri)
        with pytest.raises(ServiceError) as e:
            connection._retry(client.get_experiment_by_name, "x")
        assert client.calls == 1
        tries = 1 + int(os.environ["MLFLOW_HTTP_REQUEST_MAX_RETRIES"])  # MLflow's own, per call
        assert (
            len(server.held) == tries + 1
        )  # one call's tries and one /health probe; was 5 x (tries + 1)
        assert "accepts connections but does not answer" in str(e.value) and "\n" not in str(
            e.value
        )
        assert "local results are kept" in str(e.value)
    finally:
        server.close()


def test_a_server_that_refuses_is_still_retried(monkeypatch):
    """Refused connections are a restart, not a hang: all five attempts are made."""
    import socket

    from pcpg_dist.tracking import connection

    with socket.socket() as s:  # a free port with nothing listening
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR", "0")
    monkeypatch.setattr(connection.time, "sleep", lambda s: None)
    client = _Counting(f"http://127.0.0.1:{port}")
    with pytest.raises(ServiceError, match="failed"):
        connection._retry(client.get_experiment_by_name, "x")
    assert client.calls == 5
