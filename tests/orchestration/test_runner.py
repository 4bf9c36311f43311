"""`pcpg run` end to end on a tiny config: results, MLflow runs, resume without recomputation,
no duplicate runs, the report and the pyfunc agents."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from pcpg_dist.api.run import run_experiment
from pcpg_dist.config import load_config

ROOT = Path(__file__).resolve().parents[2]

TINY = {
    "name": "tiny",
    "seed": 1,
    "seeds": [0, 1],
    "gridworld": {
        "layout_dir": str(ROOT / "pcpg_dist" / "data" / "gridworld"),
        "environments": ["E1"],
    },
    "pbtg": {"episodes": 20000, "trajectories_per_style": 200, "dataset_per_style": 100},
    "clustering": {
        "k": 4,
        "pretrain_epochs": 6,
        "dec_epochs": 3,
        "ceiling": False,
        "confidence_runs": 0,
    },
    "ranking": {"ps": [1.0, 0.5]},
    "bc": {"epochs": 300, "hidden_size": 16},
    "evaluation": {"rollouts_per_policy": 10, "corruption_levels": [0.0, 1.0], "figures": True},
}


def results_only(metrics: dict[str, float]) -> dict[str, float]:
    """Metrics without wall-clock timings, which differ between any two runs."""
    return {k: v for k, v in metrics.items() if "seconds" not in k}


@pytest.fixture(scope="module")
def tiny_cfg(tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "tiny.yaml"
    path.write_text(yaml.safe_dump(TINY))
    return load_config(path)


@pytest.fixture(scope="module")
def first_run(ray_session, tiny_cfg, tmp_path_factory):
    work = tmp_path_factory.mktemp("work")
    uri = f"sqlite:///{work / 'mlflow.db'}"
    result = run_experiment(
        tiny_cfg,
        workdir=work / "runs",
        tracking_uri=uri,
        show_progress=False,
        command="pcpg run tiny.yaml",
    )
    return work, uri, result


@pytest.mark.slow
def test_run_produces_metrics_tables_figures(first_run):
    work, uri, result = first_run
    m = result.metrics
    assert m["clustering/accuracy"] > 0.6
    for p in ("1", "0.5"):
        assert m[f"pcpg/accuracy/p{p}"] > m["random/accuracy"] + 0.2
    summary = result.out_dir / "summary"
    for name in (
        "metrics.json",
        "accuracy_vs_p.csv",
        "accuracy_vs_p.png",
        "clustering.csv",
        "run.json",
    ):
        assert (summary / name).is_file(), name
    assert list((summary / "E1").glob("*.png")) and list((summary / "E1").glob("*.csv"))
    # one unit's cells are cut into one training group per CPU slot (2 on the test's Ray)
    assert result.computed == {"data": 1, "clustering": 1, "train_groups": 2, "evaluations": 1}
    # the summary's table holds each environment's own figures at each p (random was the
    # all-test-steps figure in every row, beside a per-p majority class)
    table, own = (
        pd.read_csv(summary / "accuracy_vs_p.csv"),
        pd.read_csv(summary / "E1" / "accuracy.csv"),
    )
    for col, method in (
        ("pcpg", "pcpg"),
        ("no_clustering", "no_clustering"),
        ("random", "random"),
        ("majority", "majority"),
    ):
        for p in (1.0, 0.5):
            want = own[(own.method == method) & (own.p == p)]["mean"].item()
            assert table[(table.env == "E1") & (table.p == p)][col].item() == pytest.approx(want), (
                col,
                p,
            )


@pytest.mark.slow
def test_mlflow_runs_metrics_artifacts_and_agents(first_run):
    import mlflow
    import pandas as pd
    from mlflow import MlflowClient

    work, uri, result = first_run
    client = MlflowClient(uri)
    exp = client.get_experiment_by_name("tiny")
    parents = client.search_runs([exp.experiment_id], filter_string="tags.`pcpg.role` = 'parent'")
    assert len(parents) == 1 and parents[0].info.status == "FINISHED"
    parent = parents[0]
    assert parent.data.params["bc.hidden_size"] == "16"
    assert {"pcpg.git_commit", "pcpg.config_hash", "pcpg.version"} <= set(parent.data.tags)
    assert parent.data.metrics["pcpg/accuracy/p0.5"] == pytest.approx(
        result.metrics["pcpg/accuracy/p0.5"]
    )
    children = client.search_runs(
        [exp.experiment_id], filter_string=f"tags.`mlflow.parentRunId` = '{parent.info.run_id}'"
    )
    assert [c.data.tags["pcpg.env"] for c in children] == ["E1"]
    child = children[0]
    assert child.info.status == "FINISHED" and "clustering/ari" in child.data.metrics
    assert any(a.path == "evaluation" for a in client.list_artifacts(child.info.run_id))
    assert {a.path for a in client.list_artifacts(parent.info.run_id)} >= {"summary", "report"}
    mlflow.set_tracking_uri(uri)
    agents = mlflow.pyfunc.load_model(f"runs:/{parent.info.run_id}/agents")
    df = pd.DataFrame(
        {
            "style": [0, 1],
            "p": [1.0, 0.5],
            "s0": [1, 1],
            "s1": [1, 1],
            "s2": [0, 0],
            "s3": [0, 0],
            "valid": [[False, True, True, False]] * 2,
        }
    )
    actions = agents.predict(df)
    assert set(actions) <= {1, 2}  # only valid actions (right, down) are ever chosen


@pytest.mark.slow
def test_rerun_recomputes_nothing_and_duplicates_nothing(first_run, tiny_cfg):
    from mlflow import MlflowClient

    work, uri, result = first_run
    again = run_experiment(tiny_cfg, workdir=work / "runs", tracking_uri=uri, show_progress=False)
    assert again.computed == {"data": 0, "clustering": 0, "train_groups": 0, "evaluations": 0}
    assert again.metrics == result.metrics
    client = MlflowClient(uri)
    exp = client.get_experiment_by_name("tiny")
    assert len(client.search_runs([exp.experiment_id])) == 2  # one parent, one child


@pytest.mark.slow
def test_ranking_shows_a_bar_of_its_own(first_run, tiny_cfg, capfd):
    """Step B (ranking, cutting units into cells) runs in the driver: on 40,000 trajectories ~15 s
    passed under a finished Step A bar before Step C's appeared. It has its own bar now."""
    work, _, result = first_run
    again = run_experiment(tiny_cfg, workdir=work / "runs", track=False, show_progress=True)
    err = capfd.readouterr().err
    assert "Step B: ranking" in err and again.metrics == result.metrics
    assert "Step A" not in err  # a stage with nothing to compute shows no bar


@pytest.mark.slow
def test_interrupted_sweep_resumes_with_same_metrics(first_run, tiny_cfg, monkeypatch):
    """Kill the sweep inside evaluation (after training finished); the rerun resumes from there."""
    from mlflow import MlflowClient

    import pcpg_dist.pipeline.tasks as tasks

    work, uri, result = first_run
    uri2 = f"sqlite:///{work / 'mlflow2.db'}"
    real = tasks.evaluate_task

    def dying(*args, **kwargs):
        raise RuntimeError("simulated crash in the evaluation stage")

    monkeypatch.setattr(tasks, "evaluate_task", dying)
    with pytest.raises(RuntimeError, match="simulated crash"):
        run_experiment(tiny_cfg, workdir=work / "runs2", tracking_uri=uri2, show_progress=False)
    monkeypatch.setattr(tasks, "evaluate_task", real)
    client = MlflowClient(uri2)
    exp = client.get_experiment_by_name("tiny")
    assert [r.info.status for r in client.search_runs([exp.experiment_id])] == ["KILLED"]
    resumed = run_experiment(
        tiny_cfg, workdir=work / "runs2", tracking_uri=uri2, show_progress=False
    )
    assert resumed.computed["clustering"] == 0 and resumed.computed["train_groups"] == 0
    assert resumed.computed["evaluations"] == 1
    assert results_only(resumed.metrics) == results_only(
        result.metrics
    )  # same numbers as uninterrupted
    runs = client.search_runs([exp.experiment_id])
    assert sorted(r.info.status for r in runs) == ["FINISHED", "FINISHED"]


@pytest.mark.slow
def test_report_renders_everything(first_run, tmp_path):
    from pcpg_dist.cli import main

    work, uri, result = first_run
    assert (
        main(
            [
                "report",
                "tiny",
                "--tracking-uri",
                uri,
                "--workdir",
                str(tmp_path),
                "--out",
                str(tmp_path / "rep"),
            ]
        )
        == 0
    )
    html = (tmp_path / "rep" / "report.html").read_text()
    md = (tmp_path / "rep" / "report.md").read_text()
    run = json.loads((result.out_dir / "summary" / "run.json").read_text())
    # the report of the logged run (MLflow keeps the first run's summary: a rerun from the cache
    # logs nothing again), so its command is the one the first run was given
    for text in (html, md):
        assert run["provenance"]["git_commit"] in text and run["provenance"]["uv_lock"] in text
        assert "pcpg run tiny.yaml" in text and "0.57 / 0.64 / 0.63 / 0.69" in text
        assert "accuracy_vs_p" in text and "Wall time per stage" in text
    assert html.count("data:image/png;base64,") >= 3
    acc = f"{result.metrics['clustering/accuracy']:.3f}"
    assert acc in md
    assert run["batch_points"] == 1 and "stages ran together" not in md  # a run's own stage times
    assert np.isfinite(result.metrics["cross/diagonal_mean"])


@pytest.mark.slow
@pytest.mark.parametrize("init", ["no_clustering", "auto"])
def test_agents_start_from_no_clustering(first_run, tiny_cfg, init, monkeypatch):
    """bc.init no_clustering (and auto, where the clustering's verdict doubts the styles): a
    second round of Ray tasks trains every per-cluster and corrupted agent from the No Clustering
    agent of its p and seed. With 0 fine-tuning epochs each must be that agent exactly; the data
    and clustering come from the cache."""
    from pcpg_dist.stages.bc import TrainedCells
    from pcpg_dist.stages.clustering import confidence

    if init == "auto":  # the runner reads the verdict of the cached clustering: make it doubt
        doubt = confidence.Verdict("no evidence of 4 styles", ())
        monkeypatch.setattr(confidence, "verdict_of", lambda metrics, k=None: doubt)
    work, _, _ = first_run
    cfg = tiny_cfg.model_copy(
        update={"bc": tiny_cfg.bc.model_copy(update={"init": init, "finetune_epochs": 0})}
    )
    train_dir = work / "runs" / "tiny" / "cache" / "train"
    before = set(train_dir.iterdir())
    result = run_experiment(cfg, workdir=work / "runs", track=False, show_progress=False)
    assert result.computed["clustering"] == 0 and result.computed["train_groups"] >= 2
    trained = TrainedCells.concat(
        [TrainedCells.load(d / "cells") for d in sorted(set(train_dir.iterdir()) - before)]
    )
    nc = {(s.p, s.seed): i for i, s in enumerate(trained.specs) if s.kind == "nc"}
    others = [i for i, s in enumerate(trained.specs) if s.kind != "nc"]
    assert {trained.specs[i].kind for i in others} == {"pcpg", "corrupt"}
    for i in others:
        s = trained.specs[i]
        for a, b in zip(
            trained.cell_params(i), trained.cell_params(nc[(s.p, s.seed)]), strict=True
        ):
            assert np.array_equal(a, b), s.key
    assert result.metrics["pcpg/accuracy/p1"] == pytest.approx(
        result.metrics["baseline/accuracy/p1"]
    )


def test_the_summary_says_which_stages_came_from_the_cache(tmp_path):
    """A rerun served from the cache printed the computing run's `generate 7.0s, cluster 14.2s`."""
    import io

    from rich.console import Console

    from pcpg_dist.orchestration.points import RunResult
    from pcpg_dist.reporting.summary import print_summary

    def printed(**kw) -> str:
        out = io.StringIO()
        print_summary(
            RunResult(out_dir=tmp_path, metrics={}, clustering={}, **kw),
            Console(file=out, width=200),
        )
        return out.getvalue().splitlines()[-1]

    times = {
        "generate": 7.0,
        "cluster": 14.2,
        "train": 30.5,
        "evaluate": 2.0,
        "summary": 0.4,
        "tracking": 0.2,
    }
    assert (
        printed(stage_seconds=times, cached_stages=["generate", "cluster", "train", "evaluate"])
        == "time per stage: summary 0.4s, tracking 0.2s; from the cache: generate, cluster, train, evaluate"
    )
    assert (
        printed(stage_seconds=times, cached_stages=["generate"])
        == "time per stage: cluster 14.2s, train 30.5s, evaluate 2.0s, summary 0.4s, tracking 0.2s; from the cache: generate"
    )
    assert (
        printed(stage_seconds=times, cached_stages=[])
        == "time per stage: generate 7.0s, cluster 14.2s, train 30.5s, evaluate 2.0s, summary 0.4s, tracking 0.2s"
    )


def test_a_failure_that_is_not_bad_input_leaves_no_empty_run_folder(
    ray_session, tiny_cfg, tmp_path, monkeypatch
):
    """Before anything is cached, any failure (here the disk, an OSError; was: only pcpg's own
    errors) removes the folders and the lock file the run created."""
    import pcpg_dist.orchestration.points as points

    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(points, "load_or_generate", disk_full)
    with pytest.raises(OSError, match="No space"):
        run_experiment(tiny_cfg, workdir=tmp_path / "runs", track=False, show_progress=False)
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow
def test_reproduce_by_mlflow_run_id_downloads_to_a_private_folder_it_removes(
    first_run, tmp_path, monkeypatch, capsys
):
    """`pcpg reproduce RUN_ID` fetched the logged summary into a fixed /tmp/pcpg-reproduce-logged,
    shared by every user of the machine and never cleaned, and recorded that path as its command."""
    import tempfile

    from mlflow import MlflowClient

    from pcpg_dist.cli import main

    work, uri, _ = first_run
    client = MlflowClient(uri)
    (parent,) = client.search_runs(
        [client.get_experiment_by_name("tiny").experiment_id],
        filter_string="tags.`pcpg.role` = 'parent'",
    )
    private = tmp_path / "tmp"
    private.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(private))
    fresh = tmp_path / "fresh"
    assert (
        main(
            [
                "reproduce",
                parent.info.run_id,
                "--tracking-uri",
                uri,
                "--workdir",
                str(fresh),
                "--quiet",
            ]
        )
        == 0
    )
    assert capsys.readouterr().out.splitlines()[-1].startswith("REPRODUCED")
    assert list(private.iterdir()) == []
    redone = json.loads(next(fresh.glob("*/summary/run.json")).read_text())
    assert redone["command"] == f"pcpg reproduce {parent.info.run_id}"


@pytest.mark.slow
def test_the_in_process_executor_gives_the_ray_runs_numbers(first_run, tiny_cfg, tmp_path):
    """The runner runs the same declared pipeline through either executor: same numbers."""
    from pcpg_dist.orchestration.executors import LocalExecutor

    _, _, on_ray = first_run
    here = run_experiment(
        tiny_cfg,
        workdir=tmp_path / "runs",
        track=False,
        show_progress=False,
        executor=LocalExecutor(),
    )
    assert results_only(here.metrics) == results_only(on_ray.metrics)
    assert here.computed == {"data": 1, "clustering": 1, "train_groups": 1, "evaluations": 1}


class _Cluster:
    """An executor's view of a Ray cluster: its CPUs in all and its smallest node's."""

    def __init__(self, cpus: int, smallest: int) -> None:
        self.cpus, self.smallest = cpus, smallest

    def slots(self, num_cpus: int) -> int:
        return max(1, self.cpus // num_cpus)

    def widest(self) -> int:
        return self.smallest


@pytest.mark.parametrize(
    ("cpus", "smallest", "jobs", "floor", "want"),
    [
        (2, 2, 1, 1, 2),  # one log on a 2-core machine: both cores (it ran on one)
        (2, 2, 2, 1, 1),  # as many jobs as CPUs: the config's one each
        (2, 2, 80, 1, 1),  # a sweep of many environments: unchanged
        (64, 8, 1, 1, 4),  # one log on a big cluster: at most 4 threads
        (64, 2, 1, 1, 2),  # ... and no more than the smallest node has (a job fits anywhere)
        (16, 16, 3, 1, 4),
        (2, 2, 1, 3, 3),  # runner.cpus_per_task is the floor
    ],
)
def test_a_few_clustering_jobs_share_every_cpu(cpus, smallest, jobs, floor, want) -> None:
    from types import SimpleNamespace

    from pcpg_dist.orchestration.runner import Batch

    point = SimpleNamespace(cfg=SimpleNamespace(runner=SimpleNamespace(cpus_per_task=floor)))
    batch = Batch([point], cache=None, executor=_Cluster(cpus, smallest), show_progress=False)
    assert batch.spread(jobs) == want


def test_the_driver_plans_training_without_torch():
    """A run's driver imports the runner, asks where BC trains and splits a unit's cells for
    ``bc.init`` without importing torch or an engine (torch alone was ~2 s of every run's CPU)."""
    import subprocess
    import sys

    code = (
        "import sys; import pcpg_dist.orchestration.runner; "
        "from pcpg_dist.config.stages import BCConfig; "
        "from pcpg_dist.orchestration.resources import bc_gpus; "
        "from pcpg_dist.stages.bc import TrainedCells, finetune_config, split_for_init; "
        "from pcpg_dist.stages.ranking import CellSpec; "
        "specs = [CellSpec('nc', 'nc', -1, 1.0, 0), CellSpec('c0', 'pcpg', 0, 1.0, 0)]; "
        "first, rest = split_for_init(specs, BCConfig(init='no_clustering')); "
        "assert [s.key for s in first] == ['nc'] and [s.key for s in rest] == ['c0']; "
        "assert finetune_config(BCConfig(init='auto', epochs=500)).epochs < 500; "
        "assert TrainedCells.FILES == ('cells.pt', 'cells.json'); "
        "print(sorted(m for m in ('torch', 'numba', 'pcpg_dist.stages.bc.train') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
