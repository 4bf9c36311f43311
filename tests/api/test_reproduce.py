"""`pcpg reproduce RUN`: a tiny real run, reproduced from its run.json in a fresh folder, matches
metric by metric; a changed metric is reported and fails; bad arguments are one line, exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pcpg_dist.api.reproduce import Reproduction, compare_metrics, print_reproduction
from pcpg_dist.config import parse_config

ROOT = Path(__file__).resolve().parents[2]

TINY = {
    "name": "repro",
    "domain": "gridworld",
    "seed": 3,
    "seeds": [0, 1],
    "gridworld": {
        "layout_dir": str(ROOT / "pcpg_dist" / "data" / "gridworld"),
        "environments": ["E1"],
    },
    "pbtg": {"episodes": 20000, "trajectories_per_style": 120, "dataset_per_style": 60},
    "clustering": {
        "k": 4,
        "pretrain_epochs": 4,
        "dec_epochs": 2,
        "ceiling": False,
        "confidence_runs": 0,
    },
    "ranking": {"ps": [1.0, 0.5]},
    "bc": {"epochs": 200, "hidden_size": 16},
    "evaluation": {"rollouts_per_policy": 8, "corruption_levels": [0.0, 1.0], "figures": False},
}


def tiny_log():
    """A two-trajectory step table: the smallest log a `trajectories` config reads."""
    import pandas as pd

    return pd.DataFrame(
        {
            "trajectory": [0, 0, 1, 1],
            "t": [0, 1, 0, 1],
            "s0": [0.0, 1.0, 0.0, 2.0],
            "action": [1, 0, 2, 0],
            "reward": [0.0, 1.0, 0.0, 1.0],
        }
    )


@pytest.fixture(scope="module")
def logged_run(ray_session, tmp_path_factory) -> Path:
    from pcpg_dist.api.run import run_experiment

    cfg = parse_config(TINY, source="tiny")
    work = tmp_path_factory.mktemp("logged")
    result = run_experiment(
        cfg, workdir=work, track=False, show_progress=False, command="pcpg run tiny.yaml"
    )
    return result.out_dir


@pytest.mark.slow
def test_reproduce_matches_every_metric(logged_run, tmp_path, capsys):
    from pcpg_dist.cli import main

    fresh = tmp_path / "fresh"
    assert main(["reproduce", str(logged_run), "--workdir", str(fresh), "--quiet"]) == 0
    out = capsys.readouterr().out.splitlines()
    logged = json.loads((logged_run / "summary" / "metrics.json").read_text())
    results = [k for k in logged if "seconds" not in k]
    lines = {line.split()[1]: line.split()[0] for line in out[:-1] if not line.startswith("note:")}
    assert set(lines) == set(results)  # one line per result metric, timings left out
    assert set(lines.values()) <= {"exact", "within"}
    assert out[-1].startswith(f"REPRODUCED: {len(results)} metrics")
    # a fresh folder: the logged run's cache was neither used nor touched
    assert (fresh / "repro" / "summary" / "metrics.json").is_file()
    redone = json.loads((fresh / "repro" / "summary" / "run.json").read_text())
    assert {"clustering", "train_groups", "evaluations"} <= set(redone["computed"])
    assert all(n >= 1 for n in redone["computed"].values())  # everything computed again
    logged_run_info = json.loads((logged_run / "summary" / "run.json").read_text())
    assert redone["input_key"] == logged_run_info["input_key"]  # the same data, and it was checked


def test_compare_metrics_statuses_and_tolerance():
    logged = {"a": 0.5, "b": 1.0, "c": float("nan"), "d": 2.0, "e": 3.0, "fit_seconds": 1.0}
    new = {"a": 0.5, "b": 1.0 + 1e-9, "c": float("nan"), "d": 2.1, "f": 4.0, "fit_seconds": 9.0}
    got = {c.name: c.status for c in compare_metrics(logged, new, rtol=1e-6, atol=0.0)}
    assert got == {
        "a": "exact",
        "b": "within",
        "c": "exact",
        "d": "differs",
        "e": "missing",
        "f": "extra",
    }
    assert {c.name: c.status for c in compare_metrics(logged, new, rtol=0.0, atol=0.0)}[
        "b"
    ] == "differs"


def test_a_difference_is_printed_and_fails(tmp_path, capsys):
    rep = Reproduction(
        compare_metrics({"pcpg/accuracy/p1": 0.9, "x": 1.0}, {"pcpg/accuracy/p1": 0.8, "x": 1.0}),
        tmp_path,
        1e-6,
        1e-9,
        ["code: logged at commit abc, reproducing at def"],
    )
    assert not rep.ok
    print_reproduction(rep)
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("note: code: logged at commit abc")
    assert out[1].split()[:2] == ["differs", "pcpg/accuracy/p1"] and "(diff -0.1)" in out[1]
    assert out[2].split()[:2] == ["exact", "x"]
    assert out[-1].startswith("NOT REPRODUCED: 2 metrics, 1 exact, 0 within tolerance")


def test_bad_arguments_are_one_line_errors(tmp_path, capsys):
    from pcpg_dist.cli import main

    summary = tmp_path / "run" / "summary"
    summary.mkdir(parents=True)
    (summary / "run.json").write_text(json.dumps({"config": TINY}))
    (summary / "metrics.json").write_text("{}")
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "something").write_text("x")
    assert main(["reproduce", str(tmp_path / "run"), "--workdir", str(busy)]) == 2
    assert main(["reproduce", str(tmp_path / "run"), "--rtol", "-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "not empty" in err[0] and "--rtol -1.0" in err[1]


@pytest.mark.parametrize(
    "file, text, says",
    [
        ("run.json", "[" * 100_000 + "]" * 100_000, "run.json: unreadable (maximum recursion"),
        (
            "run.json",
            json.dumps({"config": TINY, "computed": {"data": "x"}}),
            "run.json: computed 'data' is 'x'",
        ),
        (
            "metrics.json",
            '{"pcpg/accuracy/p1": "x"}',
            "metrics.json: metric 'pcpg/accuracy/p1' is 'x'",
        ),
        (
            "metrics.json",
            '{"pcpg/accuracy/p1": [1]}',
            "metrics.json: metric 'pcpg/accuracy/p1' is [1]",
        ),
    ],
)
def test_tampered_run_files_are_one_line_before_anything_runs(file, text, says, tmp_path, capsys):
    """A tampered run.json or metrics.json: exit 2, one line naming the file, before the rerun's
    folder is made (a bad metrics.json used to surface only after the whole sweep, or as a
    RecursionError traceback)."""
    from pcpg_dist.cli import main

    summary = tmp_path / "run" / "summary"
    summary.mkdir(parents=True)
    (summary / "run.json").write_text(json.dumps({"config": TINY}))
    (summary / "metrics.json").write_text("{}")
    (summary / file).write_text(text)
    workdir = tmp_path / "rerun"
    assert main(["reproduce", str(tmp_path / "run"), "--workdir", str(workdir)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        len(err) == 1 and err[0].startswith(f"pcpg: error: {summary / file}: ") and says in err[0]
    ), err
    assert not workdir.exists()


def test_reproduce_of_a_mistyped_run_creates_no_mlflow_store(tmp_path, monkeypatch, capsys):
    from pcpg_dist.cli import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    assert main(["reproduce", "nosuchrun"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        len(err) == 1 and "'nosuchrun' is neither a run's output folder nor an MLflow run" in err[0]
    )
    assert list(tmp_path.iterdir()) == []


def test_an_edited_log_is_not_reproduced_even_where_the_metrics_match(tmp_path, capsys):
    """The probe edited one reward of a run's log and `pcpg reproduce` said REPRODUCED (252 of 252
    exact): the change did not move a metric, but the rerun read other data than the run."""

    from pcpg_dist.api.reproduce import input_note
    from pcpg_dist.pipeline.declared import input_key

    log = tmp_path / "logs.parquet"
    table = tiny_log()
    table.to_parquet(log, index=False)
    cfg = parse_config(
        {
            "name": "own",
            "domain": "trajectories",
            "trajectories": {"path": str(log), "score": "return"},
            "clustering": {"k": 2},
        },
        source="own",
    )
    run = {"input_key": input_key(cfg), "config_hash": cfg.hash()}
    assert input_note(run, cfg) == (None, False)  # the same file: nothing to say
    assert input_note({}, cfg) == (
        None,
        False,
    )  # a run logged before the key was recorded: not checked
    table.loc[1, "reward"] = 5.0
    table.to_parquet(log, index=False)
    note, changed = input_note(run, cfg)
    assert changed and note.startswith(
        f"input data changed: the logged run read data of key {run['input_key']}"
    )
    # a config hash that changed too (a setting added since): said, not taken for changed data
    soft, changed = input_note({**run, "config_hash": "0123"}, cfg)
    assert (
        not changed and soft.startswith("input key: logged ") and "config hash changed too" in soft
    )
    rep = Reproduction(
        compare_metrics({"x": 1.0}, {"x": 1.0}), tmp_path, 1e-6, 1e-9, [note], input_changed=True
    )
    assert not rep.ok
    print_reproduction(rep)
    out = capsys.readouterr().out.splitlines()
    assert out[0] == f"note: {note}" and out[1].split()[:2] == ["exact", "x"]
    assert out[-1].startswith("NOT REPRODUCED (input data changed): 1 metrics, 1 exact")


def test_changed_data_is_said_in_one_line_before_anything_reruns(tmp_path, capsys):
    """`pcpg reproduce` compares the data's digest (the input key, also the MLflow dataset
    input's digest) before rerunning: a replaced log is one line, exit 1, no rerun folder."""

    from pcpg_dist.cli import main
    from pcpg_dist.pipeline.declared import input_key

    log = tmp_path / "logs.parquet"
    table = tiny_log()
    table.to_parquet(log, index=False)
    cfg = parse_config(
        {"name": "own", "domain": "trajectories", "trajectories": {"path": str(log)}},
        source="own",
    )
    summary = tmp_path / "run" / "summary"
    summary.mkdir(parents=True)
    logged = input_key(cfg)
    run = {"config": cfg.model_dump(mode="json"), "input_key": logged, "config_hash": cfg.hash()}
    (summary / "run.json").write_text(json.dumps(run))
    (summary / "metrics.json").write_text("{}")
    table.loc[1, "reward"] = 5.0
    table.to_parquet(log, index=False)
    workdir = tmp_path / "rerun"
    with pytest.raises(SystemExit) as stop:
        main(["reproduce", str(tmp_path / "run"), "--workdir", str(workdir)])
    assert stop.value.code == 1
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and out[0].startswith(
        f"NOT REPRODUCED: input data changed: the logged run read data of key {logged}"
    )
    assert out[0].endswith("nothing was rerun (--allow-changed-data reruns anyway)")
    assert not workdir.exists()


def test_a_workdir_inside_the_run_is_refused_before_anything_runs(tmp_path, capsys):
    """`--workdir` resolving into the run's own folder (directly or through a link) is one line,
    exit 2, before any rerun: it used to be refused only after a full reproduction that left
    cache/, summary/ and agents/ inside the original run."""
    from pcpg_dist.cli import main

    run = tmp_path / "runs" / "repro"
    summary = run / "summary"
    summary.mkdir(parents=True)
    (summary / "run.json").write_text(json.dumps({"config": TINY}))
    (summary / "metrics.json").write_text("{}")
    (tmp_path / "link").symlink_to(run)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    for workdir in (run / "again", tmp_path / "link" / "again", run):
        assert main(["reproduce", str(run), "--workdir", str(workdir)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "inside the run being reproduced" in err[0], err
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def test_outputs_inside_the_input_folder_are_refused_before_any_work(tmp_path, capsys):
    """`pcpg generate --out`, `pcpg run --workdir` or `pcpg cluster --out` inside the folder of
    step tables a config reads: one line, exit 2, nothing written (the outputs would be read back
    as input by the next run)."""
    import yaml

    from pcpg_dist.cli import main

    logs = tmp_path / "logs"
    logs.mkdir()
    tiny_log().to_parquet(logs / "a.parquet", index=False)
    config = tmp_path / "own.yaml"
    config.write_text(
        yaml.safe_dump(
            {
                "name": "own",
                "domain": "trajectories",
                "trajectories": {"path": str(logs)},
                "clustering": {"k": 2},
            }
        )
    )
    before = sorted(logs.rglob("*"))
    for argv in (
        ["generate", str(config), "--out", str(logs / "data")],
        ["run", str(config), "--workdir", str(logs), "--no-tracking"],
        ["cluster", str(config), "--out", str(logs / "styles")],
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"inside the input folder {logs}" in err[0], err
    assert sorted(logs.rglob("*")) == before
