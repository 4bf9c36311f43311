"""`key=value` overrides and `pcpg sweep`: axes, shared stages, tables, figures, MLflow, resume."""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from pcpg_dist.api.sweep import run_sweep
from pcpg_dist.cli import main
from pcpg_dist.common.errors import ConfigError
from pcpg_dist.config.overrides import (
    load_config_with,
    parse_range,
    parse_value,
    split_sweep_items,
    sweep_points,
)
from pcpg_dist.orchestration.sweep import plan_sweep, point_slug
from pcpg_dist.reporting.sweep_files import SWEEP_JSON
from pcpg_dist.reporting.sweep_page import write_sweep_files

ROOT = Path(__file__).resolve().parents[2]
QUICK = ROOT / "experiments" / "quick.yaml"

TINY = {
    "name": "sweeptiny",
    "seed": 1,
    "seeds": [0, 1],
    "gridworld": {
        "layout_dir": str(ROOT / "pcpg_dist" / "data" / "gridworld"),
        "environments": ["E1"],
    },
    "pbtg": {"episodes": 20000, "trajectories_per_style": 120, "dataset_per_style": 60},
    "clustering": {
        "k": 4,
        "method": "lstm_dec",
        "pretrain_epochs": 4,
        "dec_epochs": 2,
        "ceiling": False,
        "confidence_runs": 0,
    },
    "ranking": {"ps": [1.0, 0.5]},
    "bc": {"epochs": 150, "hidden_size": 16},
    "evaluation": {"rollouts_per_policy": 5, "corruption_levels": [0.0, 1.0], "figures": False},
}


# --------------------------------------------------------------------------- overrides
def test_override_changes_the_setting_and_is_validated_like_the_file():
    cfg = load_config_with(QUICK, ["clustering.k=5", "ranking.ps=[1.0, 0.25]", "bc.lr=1e-3"])
    assert cfg.bc.lr == 0.001 and cfg.clustering.k == 5 and list(cfg.ranking.ps) == [1.0, 0.25]
    with pytest.raises(ConfigError, match="bc.lr"):
        load_config_with(QUICK, ["bc.lr=-1"])


@pytest.mark.parametrize(
    "item, closest",
    [
        ("bc.epitchs=3", "bc.epochs"),
        ("clustrng.k=3", "clustering.k"),
        ("evaluation.rollout_per_policy=3", "evaluation.rollouts_per_policy"),
    ],
)
def test_unknown_key_names_the_closest_valid_key(item, closest):
    with pytest.raises(ConfigError, match=f"did you mean '{closest}'"):
        load_config_with(QUICK, [item])


@pytest.mark.parametrize(
    "key, closest",
    [
        ("eval.greedy", "evaluation.greedy"),
        ("evals.figures", "evaluation.figures"),
        ("cfg.seed", "seed"),
        ("clustrng.k", "clustering.k"),
        ("corridor.length", None),
    ],
)
def test_an_unknown_section_is_guessed_only_by_a_setting_of_that_name(key, closest):
    from pcpg_dist.config.overrides import closest_key

    assert closest_key(key, "gridworld") == closest


def test_a_section_unlike_any_gets_no_unrelated_suggestion():
    """`corridor.length=12` (another domain's section) was answered "did you mean 'mario.event'?"."""
    with pytest.raises(ConfigError) as e:
        load_config_with(QUICK, ["corridor.length=12"])
    assert (
        str(e.value) == "unknown config key 'corridor.length'; `pcpg run --help` shows the sections"
    )


def test_unknown_key_on_the_command_line_is_one_line_exit_2(capsys):
    assert main(["run", str(QUICK), "--no-tracking", "bc.epitchs=3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bc.epochs" in err[0]
    assert main(["run", str(QUICK), "--no-tracking", "notanassignment"]) == 2


def test_values_are_read_as_yaml():
    assert parse_value("1e-3") == 0.001 and parse_value("3") == 3 and parse_value("true") is True
    assert parse_value("[1, 0.5]") == [1, 0.5] and parse_value("lstm_dec") == "lstm_dec"


def test_ranges_and_grids():
    assert parse_range("0:0.6:0.1") == [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
    assert parse_range("2:8:2") == [2, 4, 6, 8]
    assert parse_range("a:b:c") is None
    with pytest.raises(ConfigError):
        parse_range("1:0:1")
    axes, points = sweep_points(
        {
            "grid": {"clustering.k": [2, 4]},
            "zip": {"bc.epochs": [10, 20, 30], "bc.hidden_size": [4, 8, 16]},
        },
        ["bc.lr=0.01,0.1"],
        "gridworld",
    )
    assert len(points) == 2 * 2 * 3 and list(axes) == [
        "clustering.k",
        "bc.lr",
        "bc.epochs",
        "bc.hidden_size",
    ]
    assert {(p["bc.epochs"], p["bc.hidden_size"]) for p in points} == {(10, 4), (20, 8), (30, 16)}
    with pytest.raises(ConfigError, match="equally many"):
        sweep_points({"zip": {"bc.epochs": [1, 2], "bc.lr": [0.1]}}, [], "gridworld")
    with pytest.raises(ConfigError, match="did you mean"):
        sweep_points(None, ["bc.lrr=0.1,0.2"], "gridworld")
    with pytest.raises(
        ConfigError, match="sweep axis 'clustering.k': range '4:2:1': needs start <= stop"
    ):
        sweep_points(None, ["clustering.k=4:2:1"], "gridworld")


def test_sweep_mistakes_are_refused_before_anything_is_built(capsys):
    """Counted before the points are built (three axes of 1000 values grew past 3 GB), overflowing
    ranges, an axis given twice, a value repeated, an axis also fixed: one line each, exit 2."""
    with pytest.raises(ConfigError, match="the sweep has 1000000000 points; at most 10000"):
        sweep_points(
            None, ["clustering.k=1:1000:1", "bc.epochs=1:1000:1", "seed=1:1000:1"], "gridworld"
        )
    for spec in ("1e308:1e309:1", "0:1e300:1e-300"):
        with pytest.raises(ConfigError, match="more than 10000 values"):
            sweep_points(None, [f"clustering.k={spec}"], "gridworld")
    with pytest.raises(ConfigError, match="'clustering.k' is given twice"):
        sweep_points(None, ["clustering.k=2,3", "clustering.k=4,5"], "gridworld")
    with pytest.raises(ConfigError, match="repeats the value 3"):
        sweep_points(None, ["clustering.k=3,3"], "gridworld")
    with pytest.raises(ConfigError, match="under both 'grid:' and 'zip:'"):
        sweep_points({"grid": {"bc.lr": [0.1, 0.2]}, "zip": {"bc.lr": [0.3, 0.4]}}, [], "gridworld")
    assert main(["sweep", str(QUICK), "clustering.k=2,3", "clustering.k=5", "--no-tracking"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'clustering.k' is both a sweep axis and a single value" in err[0], err
    assert parse_value("1:30") == "1:30"  # YAML 1.1 read it as 90, silently


def test_a_bracketed_list_is_one_value_so_a_fixed_override(capsys):
    """`ranking.ps=[1.0,0.5]` is one value (a list), fixed like `pcpg run` sets it; it was read as
    a one-valued axis (a ranking.ps column, folder names and 10 figures against it)."""
    items = [
        "bc.hidden_size=5,8",
        "ranking.ps=[1.0,0.5]",
        "evaluation.figures=false",
        "clustering.k=2:4:1",
        "evaluation.corruption_levels=[0.0],[0.0,1.0]",
        "bc.lr=1:0:1",
    ]
    axes, fixed = split_sweep_items(items)
    assert axes == [
        "bc.hidden_size=5,8",
        "clustering.k=2:4:1",
        "evaluation.corruption_levels=[0.0],[0.0,1.0]",
        "bc.lr=1:0:1",
    ]  # a malformed range stays an axis: its check names the mistake
    assert fixed == ["ranking.ps=[1.0,0.5]", "evaluation.figures=false"]
    # on the command line: the list is a single value, so an axis over the same key clashes with it
    assert (
        main(["sweep", str(QUICK), "ranking.ps=[1.0,0.5]", "ranking.ps=0.5,0.1", "--no-tracking"])
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'ranking.ps' is both a sweep axis and a single value" in err[0], err


def test_a_yaml_range_is_a_range_not_a_base60_number(tmp_path):
    """YAML 1.1 reads `2:8:1` as the integer 7681; the config loader reads it as text (a range)."""
    path = tmp_path / "s.yaml"
    path.write_text("name: s\nbc:\n  lr: 1e-3\nsweep:\n  grid:\n    clustering.k: 2:8:1\n")
    from pcpg_dist.config.overrides import read_raw

    raw, section = read_raw(path)
    assert raw["bc"]["lr"] == 0.001
    axes, points = sweep_points(section, [], "gridworld")
    assert axes == {"clustering.k": [2, 3, 4, 5, 6, 7, 8]} and len(points) == 7


def test_point_folders_are_stable_and_safe():
    a = point_slug({"bc.lr": 0.01, "evaluation.corruption_levels": [0, 1]})
    assert a == point_slug({"bc.lr": 0.01, "evaluation.corruption_levels": [0, 1]})
    assert a != point_slug({"bc.lr": 0.02, "evaluation.corruption_levels": [0, 1]})
    assert "/" not in a and ".." not in a.replace("=0.", "")
    assert "/" not in point_slug({"gridworld.layout_dir": "../../etc"})


def test_a_points_folder_is_set_by_its_axes_and_fixed_overrides(tmp_path):
    """Two sweeps of one config with other fixed overrides never share a point folder (the second
    overwrote the first's points); the same sweep, or one value more on an axis, finds them again."""
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(TINY))

    def folders(axes, fixed=()):
        return [p.out for p in plan_sweep(cfg, axes, list(fixed), workdir=tmp_path / "runs").points]

    a = folders(["bc.hidden_size=8,16"])
    b = folders(["bc.hidden_size=8,16"], ["evaluation.rollouts_per_policy=3"])
    c = folders(["bc.hidden_size=8,16"], ["ranking.ps=[1.0,0.25]"])
    assert len(set(a) | set(b) | set(c)) == 6
    assert folders(["bc.hidden_size=8,16"]) == a and set(a) <= set(
        folders(["bc.hidden_size=8,16,32"])
    )
    for p in a + b + c:  # short, safe, named by the axis values only (a fixed value is in the hash)
        assert p.parent == tmp_path.resolve() / "runs" / "sweeptiny" / "sweep" / "points"
        assert re.fullmatch(r"bc\.hidden_size=(8|16)-[0-9a-f]{8}", p.name), p.name
    plan = plan_sweep(
        cfg, ["bc.hidden_size=8,16"], ["ranking.ps=[1.0,0.25]"], workdir=tmp_path / "runs"
    )
    assert plan.axes == {"bc.hidden_size": [8, 16]} and plan.fixed == {"ranking.ps": [1.0, 0.25]}
    assert all(list(p.cfg.ranking.ps) == [1.0, 0.25] for p in plan.points)
    assert "fixed: ranking.ps=[1.0, 0.25]" in plan.description


def fake_rows(plan) -> list[dict]:
    """Headline rows as run_sweep makes them, without running the points."""
    rows = []
    for i, (combo, point) in enumerate(zip(plan.combos, plan.points, strict=True)):
        rows.append(
            {
                **combo,
                "point": point.out.name,
                "clustering/accuracy": 0.9 - 0.01 * i,
                "clustering/accuracy/std": 0.01,
                "pcpg/accuracy/p1": 0.8 + 0.01 * i,
                "pcpg/accuracy/p1/std": 0.02,
                "baseline/accuracy/p1": 0.7,
                "pcpg_lead/p1": 0.1 + 0.01 * i,
            }
        )
    return rows


def test_sweep_files_describe_only_the_last_sweep_and_render_again(tmp_path, capsys):
    """An earlier sweep's figures are removed (33 PNGs beside a report of 13); `pcpg report` of the
    sweep folder renders the very page the sweep wrote (it said "no such folder")."""
    first = plan_sweep(
        QUICK, ["bc.hidden_size=8,16", "bc.epochs=100,200"], [], workdir=tmp_path / "runs"
    )
    write_sweep_files(first.out, first, fake_rows(first))
    assert len(list(first.out.glob("*__vs__bc.epochs.png"))) == 4
    second = plan_sweep(QUICK, ["clustering.k=3,4"], ["bc.epochs=100"], workdir=tmp_path / "runs")
    files = write_sweep_files(second.out, second, fake_rows(second))
    assert second.out == first.out
    pngs = sorted(p.name for p in second.out.glob("*.png"))
    assert pngs == sorted(f.name for f in files if f.suffix == ".png") and len(pngs) == 4
    assert all(n.endswith("__vs__clustering.k.png") for n in pngs)
    record = json.loads((second.out / SWEEP_JSON).read_text())
    assert record["axes"] == {"clustering.k": [3, 4]} and record["fixed"] == {"bc.epochs": 100}
    assert sorted(record["figures"]) == pngs
    html = (second.out / "report.html").read_text()
    assert (
        html.count("data:image/png;base64,") == 4
        and "clustering.k" in html
        and "bc.hidden_size" not in html
    )

    assert main(["report", str(second.out), "--out", str(tmp_path / "again")]) == 0
    assert (tmp_path / "again" / "report.html").read_text() == html
    assert capsys.readouterr().out.strip() == f"sweep report: {tmp_path / 'again' / 'report.html'}"
    # a whole sweep is not one run: reproduce and export say what they take, in one line
    for cmd in (
        ["reproduce", str(second.out)],
        ["export", "onnx", str(second.out), "--out", str(tmp_path / "x")],
    ):
        assert main(cmd) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert (
            len(err) == 1 and "is the folder of a whole pcpg sweep" in err[0] and "points" in err[0]
        ), err
    assert not (tmp_path / "x").exists()


def test_report_of_a_sweeps_mlflow_run_and_reproduce_names_a_point(tmp_path, capsys):
    """The run id `pcpg sweep` prints ("MLflow sweep run: ID"): report rendered the sweep's page from
    its logged files (it crashed: no 'summary' artifacts); reproduce names one of its point runs."""
    from pcpg_dist.tracking.trackers import SweepTracker, Tracker

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    plan = plan_sweep(
        QUICK, ["bc.hidden_size=8,16"], ["ranking.ps=[1.0,0.5]"], workdir=tmp_path / "runs"
    )
    files = write_sweep_files(plan.out, plan, fake_rows(plan))
    sweep = SweepTracker.start(plan.base.name, "key", plan.axes, plan.description, uri)
    point = Tracker.start(
        plan.points[0].cfg,
        uri,
        plan.points[0].out,
        parent_run_id=sweep.parent_id,
        params=plan.points[0].params,
    )
    sweep.finish({}, files)
    for target in (sweep.parent_id, "quick"):  # the experiment's newest top-level run is the sweep
        assert (
            main(
                [
                    "report",
                    target,
                    "--tracking-uri",
                    uri,
                    "--workdir",
                    str(tmp_path / "dl"),
                    "--out",
                    str(tmp_path / target),
                ]
            )
            == 0
        ), capsys.readouterr().err
        assert (tmp_path / target / "report.html").read_text() == (
            plan.out / "report.html"
        ).read_text()
    capsys.readouterr()
    assert main(["reproduce", sweep.parent_id, "--tracking-uri", uri]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        len(err) == 1
        and "is the MLflow run of a whole pcpg sweep" in err[0]
        and point.parent_id in err[0]
    ), err


def noise_x_k_rows() -> tuple[dict, list[dict]]:
    """The reviewer's grid: k = 4 and 5 give the same clusters at every noise level."""
    axes = {"pbtg.noise_max": [0.1, 0.3], "clustering.k": [3, 4, 5]}
    rows = []
    for noise in axes["pbtg.noise_max"]:
        for k in axes["clustering.k"]:
            rows.append(
                {
                    "pbtg.noise_max": noise,
                    "clustering.k": k,
                    "point": f"{noise}-{k}",
                    "clustering/accuracy": (0.8 if k == 3 else 0.95) - noise / 10,
                    "pcpg/accuracy/p1": 0.9 - noise / 10 + k / 100,
                    "pcpg/accuracy/p1/std": 0.01,
                    "baseline/accuracy/p1": 0.8,
                    "pcpg/accuracy/p0.5": 0.85,
                    "baseline/accuracy/p0.5": 0.7,
                    "pcpg_lead/p0.5": 0.15 + (0.01 if (noise, k) == (0.3, 3) else 0.0),
                }
            )
    return axes, rows


def test_sweep_figures_tick_the_swept_values_label_axes_and_keep_equal_lines_visible(
    tmp_path, monkeypatch
):
    """k = 3, 4, 5 was drawn with ticks 3.00, 3.25, …; k = 4 and 5 (equal) hid each other; titles and
    axes were raw keys and the error bars unexplained."""
    import matplotlib.figure

    from pcpg_dist.reporting.sweep_figures import draw_sweep

    seen = {}
    save = matplotlib.figure.Figure.savefig

    def spy(fig, *args, **kwargs):
        ax = fig.axes[0]
        seen[(ax.get_xlabel(), ax.get_ylabel())] = (
            ax.get_title(),
            [t.get_text() for t in ax.get_xticklabels()],
            list(ax.get_xticks()),
            ax.get_legend_handles_labels()[1],
            [tuple(line.get_xdata()) for line in ax.lines if len(line.get_xdata()) > 1],
        )
        return save(fig, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", spy)
    axes, rows = noise_x_k_rows()
    paths = draw_sweep(tmp_path, axes, rows)
    assert len(paths) == 2 * 6 and all(p.is_file() for p in paths)
    k_label, noise_label = (
        "k (clusters) (clustering.k)",
        "largest per-trajectory action noise (pbtg.noise_max)",
    )
    title, ticks, xs, legend, _ = seen[(k_label, "PCPG accuracy at p = 1")]
    assert ticks == ["3", "4", "5"] and xs == [3.0, 4.0, 5.0]
    assert "error bars: std over seeds" in title and legend == ["noise_max=0.1", "noise_max=0.3"]
    title, ticks, _, legend, lines = seen[(noise_label, "clustering accuracy")]
    assert ticks == ["0.1", "0.3"] and "no error bars" in title
    assert legend == ["k=3", "k=4 (same as k=5)", "k=5 (same as k=4)"]
    assert len(set(lines)) == 3  # side by side, never drawn on top of each other
    assert (noise_label, "PCPG lead over No Clustering at p = 0.5") in seen


def test_best_points_name_the_point_and_its_ties():
    from pcpg_dist.orchestration.sweep import best_points

    axes, rows = noise_x_k_rows()
    best, where = best_points(axes, rows)
    assert best["best/pcpg/accuracy/p1"] == pytest.approx(0.9 - 0.01 + 0.05)
    assert where["pcpg/accuracy/p1"] == "noise_max=0.1 k=5"
    assert where["clustering/accuracy"] == "noise_max=0.1 k=4 (+1 tied)"
    assert where["pcpg_lead/p0.5"] == "noise_max=0.3 k=3"


# --------------------------------------------------------------------------- end to end
def read_rows(path: Path) -> list[dict[str, str]]:
    with open(path) as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def tiny_yaml(tmp_path_factory):
    path = tmp_path_factory.mktemp("sweepcfg") / "tiny.yaml"
    path.write_text(yaml.safe_dump({**TINY, "sweep": {"grid": {"bc.hidden_size": [8, 16]}}}))
    return path


@pytest.fixture(scope="module")
def uninterrupted(ray_session, tiny_yaml, tmp_path_factory):
    """The tiny sweep run once, in-process and never interrupted: (result, tracking URI, folder,
    its summary rows as first written; a test may add points to the folder later)."""
    tmp_path = tmp_path_factory.mktemp("uninterrupted")
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    first = run_sweep(
        tiny_yaml,
        ["bc.epochs=100,200"],
        workdir=tmp_path / "runs",
        tracking_uri=uri,
        show_progress=False,
    )
    return first, uri, tmp_path, read_rows(first.out_dir / "summary.csv")


@pytest.mark.slow
def test_sweep_shares_stages_logs_once_and_resumes(tiny_yaml, uninterrupted):
    from mlflow import MlflowClient

    first, uri, tmp_path, _ = uninterrupted
    assert len(first.rows) == 4 and first.ran == 4
    # one dataset and one clustering for four points; four distinct BC trainings and evaluations
    assert first.computed["data"] == 1 and first.computed["clustering"] == 1
    assert first.computed["evaluations"] == 4
    rows = read_rows(first.out_dir / "summary.csv")
    assert [r["bc.hidden_size"] for r in rows] == ["8", "8", "16", "16"]
    assert all(
        float(r["clustering/accuracy"]) == float(rows[0]["clustering/accuracy"]) for r in rows
    )
    assert all(
        0 <= float(r["pcpg/accuracy/p1"]) <= 1 and r["pcpg/accuracy/p1/std"] != "" for r in rows
    )
    assert len({r["pcpg/accuracy/p1"] for r in rows}) > 1  # the BC settings did change the agents
    figs = sorted(p.name for p in first.out_dir.glob("*.png"))
    assert (
        "pcpg_accuracy_p1__vs__bc.epochs.png" in figs
        and "clustering_accuracy__vs__bc.hidden_size.png" in figs
    )
    html = (first.out_dir / "report.html").read_text()
    assert html.count("data:image/png;base64,") == len(figs) and "bc.hidden_size" in html
    # each point's own report says its stage times are the batch's (they were shown as its own)
    for point in (first.out_dir / "points").iterdir():
        assert json.loads((point / "summary" / "run.json").read_text())["batch_points"] == 4
        assert (
            "one of 4 sweep points whose stages ran together"
            in (point / "report" / "report.md").read_text()
        )

    client = MlflowClient(uri)
    exp = client.get_experiment_by_name("sweeptiny")
    runs = client.search_runs([exp.experiment_id], max_results=1000)
    sweep_runs = [r for r in runs if r.info.run_id == first.parent_run_id]
    points = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == first.parent_run_id]
    assert len(sweep_runs) == 1 and len(points) == 4
    assert {(r.data.params["bc.hidden_size"], r.data.params["bc.epochs"]) for r in points} == {
        ("8", "100"),
        ("8", "200"),
        ("16", "100"),
        ("16", "200"),
    }
    assert all(r.info.status == "FINISHED" for r in runs)
    # points named by their axis values, no stage times of their own; the sweep run has them and
    # names its best points
    assert sorted(r.info.run_name for r in points) == [
        "hidden_size=16 epochs=100",
        "hidden_size=16 epochs=200",
        "hidden_size=8 epochs=100",
        "hidden_size=8 epochs=200",
    ]
    assert not any(k.startswith("time/") for r in points for k in r.data.metrics)
    sweep_run = sweep_runs[0]
    assert {"time/train_seconds", "time/sweep_seconds", "best/pcpg/accuracy/p1"} <= set(
        sweep_run.data.metrics
    )
    best = max(points, key=lambda r: r.data.metrics["pcpg/accuracy/p1"])
    assert sweep_run.data.tags["pcpg.best_point/pcpg/accuracy/p1"].startswith(best.info.run_name)
    assert "Best points: " in sweep_run.data.tags["mlflow.note.content"]

    # the points share one dataset: the sweep run, every point and its environments name it once
    def digests(run) -> list[tuple[str, str]]:
        got = client.get_run(run.info.run_id).inputs.dataset_inputs
        return sorted((d.dataset.digest, d.tags[0].value) for d in got)

    a_point = next((first.out_dir / "points").iterdir())
    data_digest = json.loads((a_point / "summary" / "run.json").read_text())["input_key"]
    assert all(digests(r) == digests(sweep_run) for r in runs)
    assert len(digests(sweep_run)) == 2 and (data_digest, "training") in digests(sweep_run)
    n_runs = len(runs)

    # the same command again: nothing runs, nothing is logged twice, the table is identical
    again = run_sweep(
        tiny_yaml,
        ["bc.epochs=100,200"],
        workdir=tmp_path / "runs",
        tracking_uri=uri,
        show_progress=False,
    )
    assert again.ran == 0 and again.parent_run_id == first.parent_run_id
    assert read_rows(again.out_dir / "summary.csv") == rows
    assert len(client.search_runs([exp.experiment_id], max_results=1000)) == n_runs

    # a new value on an axis runs only the new points
    more = run_sweep(
        tiny_yaml,
        ["bc.epochs=100,200,300"],
        workdir=tmp_path / "runs",
        tracking_uri=uri,
        show_progress=False,
    )
    assert more.ran == 2 and more.computed["clustering"] == 0 and more.computed["data"] == 0
    new_rows = read_rows(more.out_dir / "summary.csv")
    assert [r for r in new_rows if r["bc.epochs"] != "300"] == rows
    # its MLflow run has a child per point: the two it ran, and copies of the four it reused
    # (it had only the new two, while naming its best points among the others)
    kids = [
        r
        for r in client.search_runs([exp.experiment_id], max_results=1000)
        if r.data.tags.get("mlflow.parentRunId") == more.parent_run_id
    ]
    assert len(kids) == 6 and all(r.info.status == "FINISHED" for r in kids)
    copies = {r.data.tags["pcpg.same_as"]: r for r in kids if "pcpg.same_as" in r.data.tags}
    assert set(copies) == {r.info.run_id for r in points}
    for src in points:
        copy = copies[src.info.run_id]
        assert copy.info.run_name == src.info.run_name and copy.data.params == src.data.params
        assert copy.data.metrics == src.data.metrics
        own, copied = (
            {
                k: sorted((m.step, m.value) for m in client.get_metric_history(run_id, k))
                for k in src.data.metrics
            }
            for run_id in (src.info.run_id, copy.info.run_id)
        )
        assert copied == own and any(len(h) > 1 for h in own.values())  # its curves over p too
    named = {
        t
        for k, t in client.get_run(more.parent_run_id).data.tags.items()
        if k.startswith("pcpg.best_point/")
    }
    assert all(any(t.startswith(r.info.run_name) for r in kids) for t in named)
    n_now = len(client.search_runs([exp.experiment_id], max_results=1000))
    run_sweep(
        tiny_yaml,
        ["bc.epochs=100,200,300"],
        workdir=tmp_path / "runs",
        tracking_uri=uri,
        show_progress=False,
    )
    assert len(client.search_runs([exp.experiment_id], max_results=1000)) == n_now  # no copy twice


@pytest.mark.slow
def test_sweep_killed_at_any_moment_resumes_to_identical_tables(tmp_path, tiny_yaml, uninterrupted):
    """kill -9 a `pcpg sweep` mid-way; rerunning the same command gives the uninterrupted tables
    (those of the same sweep run in-process on the session's Ray, never killed)."""
    cmd = [
        sys.executable,
        "-m",
        "pcpg_dist.cli",
        "sweep",
        str(tiny_yaml),
        "bc.epochs=100,200",
        "--quiet",
        "--workdir",
        str(tmp_path / "runs"),
        "--tracking-uri",
        f"sqlite:///{tmp_path / 'mlflow.db'}",
    ]
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_ADDRESS", "MLFLOW_TRACKING_URI")}
    proc = subprocess.Popen(
        cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    cache = tmp_path / "runs" / "sweeptiny" / "cache" / "train"
    deadline = time.monotonic() + 600
    while (
        time.monotonic() < deadline
        and proc.poll() is None
        and not (cache.exists() and any(cache.iterdir()))
    ):
        time.sleep(0.5)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    a = read_rows(tmp_path / "runs" / "sweeptiny" / "sweep" / "summary.csv")
    *_, b = uninterrupted  # the uninterrupted sweep's rows
    assert a == b and len(a) == 4
    from mlflow import MlflowClient

    client = MlflowClient(f"sqlite:///{tmp_path / 'mlflow.db'}")
    exp = client.get_experiment_by_name("sweeptiny")
    runs = client.search_runs([exp.experiment_id], max_results=1000)
    assert not [r for r in runs if r.info.status == "RUNNING"]
    roots = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    assert len(roots) == 1  # one sweep run, never a duplicate after the kill
    points = [
        r
        for r in runs
        if r.data.tags.get("mlflow.parentRunId") == roots[0].info.run_id
        and r.info.status == "FINISHED"
    ]
    assert len(points) == 4


@pytest.mark.slow
def test_another_sweeps_fixed_override_leaves_this_sweeps_points_done(tiny_yaml, uninterrupted):
    """A sweep with a fixed override wrote into the first sweep's point folders (same axis values),
    so rerunning the first recomputed them ("2 run now"); the folder kept the other's figures."""
    first, uri, tmp_path, rows = uninterrupted
    other = run_sweep(
        tiny_yaml,
        ["bc.epochs=100,200"],
        ["evaluation.rollouts_per_policy=3"],
        workdir=tmp_path / "runs",
        tracking_uri=uri,
        show_progress=False,
    )
    assert other.ran == 4 and other.computed["train_groups"] == 0  # only the evaluation differs
    assert not {r["point"] for r in other.rows} & {r["point"] for r in rows}
    again = run_sweep(
        tiny_yaml,
        ["bc.epochs=100,200"],
        workdir=tmp_path / "runs",
        tracking_uri=uri,
        show_progress=False,
    )
    assert again.ran == 0 and read_rows(again.out_dir / "summary.csv") == rows
    assert sorted(again.out_dir.glob("*.png")) == sorted(again.figures)
