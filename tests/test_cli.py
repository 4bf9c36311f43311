"""The `pcpg` command line: data generation on Ray and one-line errors with exit code 2."""

from __future__ import annotations

import gc
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from pcpg_dist.cli import main
from pcpg_dist.common.errors import DataError
from pcpg_dist.config import load_config
from pcpg_dist.dataset import load_datasets
from pcpg_dist.domains.gridworld.pbtg import generate_pair
from pcpg_dist.orchestration.ray_pool import run_tasks
from pcpg_dist.stages.data import generate, generate_to

ROOT = Path(__file__).resolve().parent.parent


def tiny_config(tmp_path: Path) -> Path:
    data = {
        "name": "tiny",
        "seed": 3,
        "seeds": [0],
        "gridworld": {
            "layout_dir": str(ROOT / "pcpg_dist" / "data" / "gridworld"),
            "environments": ["E1", "E3"],
        },
        "pbtg": {"episodes": 3000, "trajectories_per_style": 200, "dataset_per_style": 50},
    }
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_generate_writes_a_checked_dataset(ray_session, tmp_path):
    cfg = load_config(tiny_config(tmp_path))
    written = generate_to(cfg, tmp_path / "data", show_progress=False)
    loaded = load_datasets(tmp_path / "data")
    assert set(loaded) == {"E1", "E3"}
    for env, ds in loaded.items():
        assert ds.n_trajectories == 200 and list(np.bincount(ds.styles)) == [50] * 4
        np.testing.assert_array_equal(ds.states, written[env].states)


def test_data_is_bit_identical_with_one_or_two_workers(ray_session, tmp_path):
    from pcpg_dist.orchestration import ray_pool

    cfg = load_config(tiny_config(tmp_path))
    two = generate(cfg, False, ray_pool.fan_out)  # 1-CPU tasks: two run at once
    layouts = [(e, r) for e in ("E1", "E3") for r in range(4)]
    from pcpg_dist.domains.gridworld.domain import gridworld_layouts

    lay = {lt.name: lt for lt in gridworld_layouts(cfg)}
    # 2-CPU tasks on a 2-CPU Ray: one worker at a time, in another order.
    one = run_tasks(
        generate_pair,
        [(lay[e], r, cfg.pbtg, cfg.seed) for e, r in reversed(layouts)],
        "one worker",
        num_cpus=2,
        show_progress=False,
    )
    for (e, r), part in zip(reversed(layouts), one, strict=True):
        whole = two[e]
        sel = whole.subset(np.nonzero(whole.styles == r)[0])
        np.testing.assert_array_equal(sel.states, part.states)
        np.testing.assert_array_equal(sel.epsilon, part.epsilon)


def test_failing_task_is_one_line_and_the_rest_are_cancelled_quietly(ray_session, capfd, caplog):
    def task(i):  # defined here, so Ray ships it by value
        if i == 0:
            time.sleep(0.5)
            raise DataError("task 0: bad input")
        start = time.time()
        while time.time() - start < 3:  # still running when task 0 fails
            pass
        raise DataError(f"task {i}: fails later")

    with pytest.raises(DataError, match="task 0: bad input") as raised:
        run_tasks(task, [(0,), (1,)], "fails", show_progress=False)
    del raised  # its traceback holds run_tasks' references to the other task
    gc.collect()
    time.sleep(5)  # past the moment task 1 would have failed unread
    err = capfd.readouterr().err + caplog.text
    assert "fails later" not in err and "Unhandled error" not in err


def test_cli_errors_are_one_line_with_exit_code_2(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\npbtg:\n  noise_max: 7\n")
    assert main(["generate", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "pbtg.noise_max" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_console_script_help_lists_commands():
    out = subprocess.run(
        [sys.executable, "-m", "pcpg_dist.cli", "--help"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert "generate" in out


@pytest.mark.parametrize("argv", [["generate"], ["nope"]])
def test_usage_errors_exit_2(argv):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2


def test_domains_lists_the_builtins(capsys):
    from pcpg_dist.cli import main

    assert main(["domains"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [ln.split()[0] for ln in lines[:4]] == [
        "gridworld",
        "minidungeons",
        "mario",
        "trajectories",
    ]
    assert all(ln.split()[1] == "built-in" for ln in lines[:4])


def test_classify_writes_the_models_labels_and_warns_on_another_layout(
    tmp_path, capsys, monkeypatch
):
    import pandas as pd

    from pcpg_dist.dataset import write_parquet
    from pcpg_dist.domains.gridworld.layout import random_layouts
    from pcpg_dist.domains.gridworld.pbtg import assemble_dataset
    from pcpg_dist.domains.gridworld.settings import PBTGConfig
    from pcpg_dist.stages.clustering import ClusterConfig, cluster

    pbtg = PBTGConfig(episodes=3000, trajectories_per_style=60, dataset_per_style=40)
    same, other = random_layouts(2, 11)
    fitted = assemble_dataset([generate_pair(same, r, pbtg, 0) for r in range(4)])
    res = cluster(fitted, ClusterConfig(k=4), seed=0)
    res.model.save(tmp_path / "model")
    fresh = assemble_dataset([generate_pair(same, r, pbtg, 1) for r in range(4)])  # new players
    elsewhere = assemble_dataset([generate_pair(other, r, pbtg, 0) for r in range(4)])
    write_parquet(fresh, tmp_path / "fresh.parquet")
    write_parquet(elsewhere, tmp_path / "elsewhere.parquet")

    assert (
        main(
            [
                "classify",
                str(tmp_path / "model"),
                str(tmp_path / "fresh.parquet"),
                "--out",
                str(tmp_path / "fresh.csv"),
            ]
        )
        == 0
    )
    table = pd.read_csv(tmp_path / "fresh.csv")
    assert table["trajectory"].tolist() == fresh.trajectory_ids.tolist()
    assert (table["predicted_style"].to_numpy() == res.model.predict(fresh)).all()
    out, err = capsys.readouterr()
    assert (
        "against the true styles" in out and "not fitted on" in out and "WARNING" not in err.upper()
    )
    assert res.model.unknown_rows(fresh) < 0.1

    assert (
        main(
            [
                "classify",
                str(tmp_path / "model"),
                str(tmp_path / "elsewhere.parquet"),
                "--out",
                str(tmp_path / "elsewhere.csv"),
            ]
        )
        == 0
    )
    share = res.model.unknown_rows(elsewhere)
    assert share > 0.1
    out, err = capsys.readouterr()
    assert f"{share:.0%} of the rows are in states the model was not fitted on" in out
    assert "elsewhere.parquet" in err and "same layout or game" in err

    # without --out: <dataset stem>.styles.csv in the current folder, never beside the dataset
    data, here = tmp_path / "data", tmp_path / "here"
    data.mkdir(), here.mkdir()
    write_parquet(fresh, data / "fresh.parquet")
    monkeypatch.chdir(here)
    assert main(["classify", str(tmp_path / "model"), str(data / "fresh.parquet")]) == 0
    assert sorted(p.name for p in data.iterdir()) == ["fresh.parquet"]
    pd.testing.assert_frame_equal(pd.read_csv(here / "fresh.styles.csv"), table)
    assert "-> fresh.styles.csv" in capsys.readouterr().out


def test_a_ray_address_where_nothing_answers_is_one_line_at_once(tmp_path):
    """Ray waited ~14 min on a dead head (821 s measured), printing its C++ log all the while; on a
    port where another service answers (MLflow's, a database's) it waited without end."""
    import http.server
    import threading

    web = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    threading.Thread(target=web.serve_forever, daemon=True).start()
    other = f"127.0.0.1:{web.server_address[1]}"
    for address, says in [
        ("127.0.0.1:1", "no Ray cluster answers at 127.0.0.1:1"),
        ("ray://127.0.0.1:1", "no Ray cluster answers"),
        ("foo", "expected HOST:PORT"),
        ("http://127.0.0.1:8265", "not a http:// URL"),
        (other, f"{other} answers, but not as a Ray head does"),
    ]:
        out = subprocess.run(
            [
                sys.executable,
                "-m",
                "pcpg_dist.cli",
                "generate",
                str(ROOT / "experiments" / "quick.yaml"),
                "--out",
                str(tmp_path / "data"),
                "--ray-address",
                address,
            ],
            capture_output=True,
            text=True,
            timeout=120,
            cwd=tmp_path,
        )
        err = out.stderr.strip().splitlines()
        assert out.returncode == 2 and len(err) == 1 and says in err[0], (
            address,
            out.stderr[-2000:],
        )
        assert not (tmp_path / "data").exists()
    web.shutdown()


@pytest.mark.slow
def test_cluster_command_writes_labels_and_margins_per_environment(ray_session, tmp_path):
    cfg = {
        "name": "c",
        "seed": 0,
        "gridworld": {
            "layout_dir": str(ROOT / "pcpg_dist" / "data" / "gridworld"),
            "environments": ["E1"],
        },
        "pbtg": {"episodes": 3000, "trajectories_per_style": 60, "dataset_per_style": 40},
    }
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(cfg))
    assert (
        main(["--quiet", "cluster", str(tmp_path / "c.yaml"), "--out", str(tmp_path / "out")]) == 0
    )
    labels = json.loads((tmp_path / "out" / "E1" / "labels.json").read_text())
    margins = json.loads((tmp_path / "out" / "E1" / "margins.json").read_text())
    assert len(labels) == len(margins) == 160 and set(labels) <= {0, 1, 2, 3}
    assert min(margins) > -1.0 and sorted(margins)[80] > 1.0  # the label is (nearly) the argmax
    # a clusterer without a likelihood has no margins to write
    assert (
        main(
            [
                "--quiet",
                "cluster",
                str(tmp_path / "c.yaml"),
                "clustering.method=bag_kmeans",
                "--out",
                str(tmp_path / "out"),
            ]
        )
        == 0
    )
    assert not any(
        "greedy_mix" in k
        for k in json.loads((tmp_path / "out" / "E1" / "metrics.json").read_text())
    )
    assert not (tmp_path / "out" / "E1" / "margins.json").exists()  # not the earlier clustering's


# every command and how to call it; the test below fails when a new command is missing here
COMMANDS = {
    "generate": ["generate", "c.yaml", "--out", "o"],
    "run": ["run", "c.yaml"],
    "sweep": ["sweep", "c.yaml", "bc.lr=0.1,0.2"],
    "cluster": ["cluster", "c.yaml", "--out", "o"],
    "classify": ["classify", "model", "d.parquet"],
    "report": ["report", "runs/x"],
    "reproduce": ["reproduce", "runs/x"],
    "tune": ["tune", "c.yaml"],
    "domains": ["domains"],
    "export onnx": ["export", "onnx", "runs/x", "--out", "o"],
    "export minari": ["export", "minari", "runs/x", "--out", "o"],
}


def test_quiet_and_verbose_are_taken_before_or_after_every_command():
    """docs/user-guide.md "The terminal": `pcpg -q COMMAND`, or -q/--quiet after the command."""
    from pcpg_dist.cli import build_parser, parse_args

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    formats = next(a for a in sub.choices["export"]._actions if a.dest == "what")
    assert set(COMMANDS) == {c for c in sub.choices if c != "export"} | {
        f"export {f}" for f in formats.choices
    }
    for name, argv in COMMANDS.items():
        plain = parse_args(argv)
        assert not plain.quiet and not plain.verbose, name
        for flags in (["-q"], ["--quiet"]):
            assert parse_args([*flags, *argv]).quiet, (name, flags)
            assert parse_args([*argv, *flags]).quiet, (name, flags)
        assert parse_args(["--verbose", *argv]).verbose, name
        after = parse_args([*argv, "--verbose"])
        assert after.verbose and not after.quiet, name
    # options after the command do not eat a sweep's axes or a run's overrides
    args = parse_args(["sweep", "c.yaml", "-q", "bc.lr=0.1,0.2"])
    assert args.quiet and args.axes == ["bc.lr=0.1,0.2"]


def test_domains_quiet_after_the_command_lists_the_domains(capsys):
    assert main(["domains", "-q"]) == 0
    assert "gridworld" in capsys.readouterr().out


def test_help_names_both_export_formats(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    shown = " ".join(capsys.readouterr().out.split())  # the help wraps lines
    export = shown.split(" export ", 1)[1].split(" options: ")[0]
    assert "ONNX" in export and "Minari" in export


def test_classify_never_overwrites_its_inputs_or_a_special_file(tmp_path, capsys):
    """`classify --out` on the dataset, the model's JSON, a FIFO or a copy of /dev/null replaced
    them with the CSV (exit 0); now one line, exit 2, and every input is byte-for-byte as before."""
    import os

    from pcpg_dist.common.files import atomic_write_bytes
    from pcpg_dist.dataset import write_parquet
    from pcpg_dist.domains.gridworld.layout import random_layouts
    from pcpg_dist.domains.gridworld.pbtg import assemble_dataset
    from pcpg_dist.domains.gridworld.settings import PBTGConfig
    from pcpg_dist.stages.clustering import ClusterConfig, cluster

    pbtg = PBTGConfig(episodes=1000, trajectories_per_style=20, dataset_per_style=10)
    (layout,) = random_layouts(1, 5)
    ds = assemble_dataset([generate_pair(layout, r, pbtg, 0) for r in range(4)])
    cluster(ds, ClusterConfig(k=4, method="visits_kmeans"), seed=0).model.save(tmp_path / "model")
    data = tmp_path / "data.parquet"
    write_parquet(ds, data)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    inputs = {p: p.read_bytes() for p in [data, *(tmp_path / "model").iterdir()]}
    for out, says in [
        (data, "is the input dataset"),
        (tmp_path / "model" / "cluster_model.json", "inside the model folder"),
        (fifo, "not a regular file"),
    ]:
        assert main(["classify", str(tmp_path / "model"), str(data), "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert says in err and len(err.strip().splitlines()) == 1, err
    assert {p: p.read_bytes() for p in inputs} == inputs and fifo.is_fifo()
    # below the CLI too: an atomic write refuses to rename over a FIFO
    with pytest.raises(OSError, match="not a regular file"):
        atomic_write_bytes(fifo, b"x")
    assert fifo.is_fifo() and sorted(p.name for p in tmp_path.iterdir()) == [
        "data.parquet",
        "fifo",
        "model",
    ]
    assert (
        main(["classify", str(tmp_path / "model"), str(data), "--out", str(tmp_path / "ok.csv")])
        == 0
    )


def test_sweep_prints_its_points_numbers_on_stdout(capsys, tmp_path):
    """`pcpg sweep` printed where its table was, and no number: now each point's headline."""
    from pcpg_dist.api.sweep import SweepResult
    from pcpg_dist.cli import _print_points

    rows = [
        {
            "pbtg.noise_max": n,
            "clustering.k": k,
            "point": f"p{n}-{k}",
            "clustering/accuracy": 0.9 + k / 100,
            "pcpg/accuracy/p1": 0.5 + n,
            "baseline/accuracy/p1": 0.75,
            "pcpg/accuracy/p0.1": 0.97,
            "baseline/accuracy/p0.1": 0.2 + n,
        }
        for n in (0.1, 0.3)
        for k in (3, 4)
    ]
    res = SweepResult(
        tmp_path, {"pbtg.noise_max": [0.1, 0.3], "clustering.k": [3, 4]}, rows, [], 1.0, 4
    )
    _print_points(res)
    out = capsys.readouterr().out
    assert all(
        f" {title} " in out
        for title in ("noise_max", "k", "clust. acc", "PCPG p1", "NC p1", "PCPG p0.1", "NC p0.1")
    ), out
    row = next(line for line in out.splitlines() if line.startswith("│ 0.3") and " 4 " in line)
    assert [c.strip() for c in row.split("│")[3:8]] == ["0.940", "0.800", "0.750", "0.970", "0.500"]


def test_a_sweep_over_k_without_labels_shows_each_points_stability(capsys, tmp_path):
    """Without labels there is no clustering accuracy: the stability is what compares the k."""
    from pcpg_dist.api.sweep import SweepResult
    from pcpg_dist.cli import _print_points
    from pcpg_dist.reporting.sweep_files import headline

    metrics = {"clustering/stability": 0.91, "clustering/stability/std": 0.02}
    metrics |= {"pcpg/accuracy/p1": 0.8, "baseline/accuracy/p1": 0.7}
    assert headline(metrics)["clustering/stability"] == 0.91  # in summary.csv and the page
    rows = [
        {"clustering.k": k, "point": f"k{k}", **headline({**metrics, "clustering/stability": s})}
        for k, s in ((3, 0.41), (4, 0.93))
    ]
    _print_points(SweepResult(tmp_path, {"clustering.k": [3, 4]}, rows, [], 1.0, 2))
    out = capsys.readouterr().out
    assert " stab. " in out and "clust. acc" not in out
    row = next(line for line in out.splitlines() if line.startswith("│ 4 "))
    assert "0.930" in row


def test_results_written_to_a_file_keep_their_table_numbers_whole():
    """Redirected stdout has no terminal width: rich's default 80 columns cut 0.953 to "0.9…"."""
    import os
    import subprocess
    import sys

    code = "from pcpg_dist.common.progress import out; print(out.width)"
    env = {k: v for k, v in os.environ.items() if k != "COLUMNS"}
    piped = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert piped.stdout.strip() == "160"
    asked = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={**env, "COLUMNS": "100"}
    )
    assert asked.stdout.strip() == "100"  # a width the user set still wins
