"""The MLflow UI on a finished run, in a real browser (Playwright + the distribution's Chromium).

The store is written by the real tracking code from a real tiny run's summary
(tests/data/report_summary: GridWorld E1, ps 1 and 0.5, its tables; figures redrawn), then
`mlflow server` serves it on a free port. Checked: the experiment opens on its runs table (not the
GenAI overview) listing the parent and its environment run; the parent's page shows its
description and its summary figure loads; the chart view draws the accuracy-over-p curve.
Screenshots go to outputs/test-artifacts/mlflow_ui (kept by CI). Without Chromium the tests skip,
saying so.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from bc_toy import make_dataset

from pcpg_dist.config import load_config
from pcpg_dist.domains.base import Unit
from pcpg_dist.orchestration.points import RunResult
from pcpg_dist.pipeline.declared import input_key
from pcpg_dist.stages import figures
from pcpg_dist.tracking.children import log_environment
from pcpg_dist.tracking.logged import ui_link
from pcpg_dist.tracking.trackers import Tracker

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).parents[1] / "data" / "report_summary"
ARTIFACTS = (
    Path(os.environ.get("PCPG_TEST_ARTIFACTS", ROOT / "outputs" / "test-artifacts")) / "mlflow_ui"
)
WIDTH = 1280
ML = "workflowType=machine_learning"  # MLflow 3.17's UI switch for classic ML pages (see tracking.logged.ui_link)

pytestmark = pytest.mark.slow


def chromium_path() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> dict:
    """A finished tiny run logged as `pcpg run` logs it: a parent and one environment child."""
    base = tmp_path_factory.mktemp("ui")
    out = base / "runs" / "tiny"
    summary = out / "summary"
    shutil.copytree(DATA, summary)
    figures.redraw(summary)
    metrics = json.loads((summary / "metrics.json").read_text())
    envs = sorted({k.split("/")[0] for k in metrics if k.startswith("E") and "/" in k})
    clustering = {
        e: {k.split("/", 1)[1]: v for k, v in metrics.items() if k.startswith(f"{e}/clustering/")}
        for e in envs
    }
    cfg = load_config(ROOT / "experiments" / "quick.yaml")
    uri = f"sqlite:///{base / 'mlflow.db'}"
    toy = make_dataset(n_per_style=5)  # profiled: 10 trajectories, 2 of them held out
    units = [Unit("E1", toy, np.array([0, 5]))]
    tracker = Tracker.start(cfg, uri, out, ikey=input_key(cfg), units=units)
    for env in envs:
        per_env = {k.split("/", 1)[1]: v for k, v in metrics.items() if k.startswith(f"{env}/")}
        log_environment(
            tracker.child_info(env, f"unit-{env}", clustering[env]),
            env,
            str(summary / env),
            per_env,
            [],
        )
    result = RunResult(
        out,
        metrics,
        clustering,
        {"generate": 30.0, "cluster": 12.0, "train": 40.0, "evaluate": 9.0, "summary": 2.0},
    )
    tracker.finish(result)
    return {
        "uri": uri,
        "tracker": tracker,
        "envs": envs,
        "run_name": f"{cfg.name}-{cfg.hash()[:8]}",
        "ikey": input_key(cfg),
    }


@pytest.fixture(scope="module")
def server(store, tmp_path_factory):
    port = free_port()
    log = tmp_path_factory.mktemp("server") / "mlflow.log"
    cmd = [
        str(Path(sys.executable).parent / "mlflow"),
        "server",
        "--backend-store-uri",
        store["uri"],
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
        "--workers",
        "1",
    ]
    with open(log, "w") as fh:
        # no GenAI job runner (~8 extra processes; pcpg needs none), as ops/services.sh does
        env = {**os.environ, "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"}
        proc = subprocess.Popen(
            cmd, stdout=fh, stderr=subprocess.STDOUT, start_new_session=True, env=env
        )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = (
            time.monotonic() + 420
        )  # minutes on a loaded 2-core machine (~3 min seen at load 17)
        while True:
            try:
                with urllib.request.urlopen(url + "/health", timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                pass
            if proc.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"mlflow server did not start:\n{log.read_text()[-3000:]}")
            time.sleep(0.5)
        yield url
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)


@pytest.fixture(scope="module")
def browser():
    exe = chromium_path()
    if exe is None:
        pytest.skip(
            "no Chromium found (install the distribution package: apt-get install -y chromium)"
        )
    from playwright.sync_api import sync_playwright

    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=exe, args=["--no-sandbox"])
        yield b
        b.close()


@pytest.fixture
def page(browser, request):
    pg = browser.new_page(viewport={"width": WIDTH, "height": 900})
    # the UI's first load compiles a large bundle: minutes on a loaded 2-core machine
    pg.set_default_timeout(240_000)
    yield pg
    pg.screenshot(
        path=str(ARTIFACTS / f"last_{request.node.name}.png")
    )  # what it showed at the end (or failure)
    pg.close()


def test_printed_link_opens_the_runs_table(page, server, store):
    """`pcpg run` prints ui_link(): the experiment's runs table, parent and environment runs listed."""
    tracker = store["tracker"]
    page.goto(ui_link(store["uri"], tracker.parent_id, ui=server))
    page.get_by_text(store["run_name"], exact=True).first.wait_for()
    assert f"/experiments/{tracker.experiment_id}/runs" in page.url, (
        page.url
    )  # not the GenAI overview
    page.get_by_text("2 matching runs").wait_for()  # the parent and its environment run
    parent_cell = page.locator("[role=gridcell]", has_text=store["run_name"]).first
    parent_cell.locator("button").first.click()  # the run name's expander shows the nested child
    for env in store["envs"]:
        page.get_by_text(env, exact=True).first.wait_for()
    page.screenshot(path=str(ARTIFACTS / "experiment_runs.png"))


def test_parent_run_has_description_and_its_figure_loads(page, server, store):
    tracker = store["tracker"]
    base = f"{server}/#/experiments/{tracker.experiment_id}/runs/{tracker.parent_id}"
    page.goto(f"{base}?{ML}")
    page.get_by_text(
        "PCPG vs No Clustering accuracy", exact=False
    ).first.wait_for()  # the run description
    page.screenshot(path=str(ARTIFACTS / "parent_overview.png"), full_page=True)
    page.goto(f"{base}/artifacts/summary/accuracy_vs_p.png?{ML}")
    page.get_by_text("summary/accuracy_vs_p.png").first.wait_for()
    # the figure's bytes arrived and decoded: an image as wide as the PNG the run wrote
    page.wait_for_function(
        "() => [...document.images].some(i => i.complete && i.naturalWidth > 300)"
    )
    page.screenshot(path=str(ARTIFACTS / "parent_figure.png"))


def test_parent_charts_draw_the_curve_over_p(page, server, store):
    tracker = store["tracker"]
    page.goto(
        f"{server}/#/experiments/{tracker.experiment_id}/runs/{tracker.parent_id}/model-metrics?{ML}"
    )
    page.get_by_text("accuracy_vs_p/pcpg", exact=False).first.wait_for()
    page.wait_for_timeout(3000)  # let the plots draw before the screenshot
    page.screenshot(path=str(ARTIFACTS / "parent_charts.png"), full_page=True)
    text = page.locator("body").inner_text()
    assert "/std" not in text  # no std chart sections
    assert "E1/" not in text  # no per-environment copies on the parent


def test_runs_table_shows_the_data_each_run_used(page, server, store):
    """The Dataset column lists the run's data (name and digest: the data's input key), as
    MLflow shows any dataset input, and its drawer says where the data came from."""
    tracker = store["tracker"]
    page.goto(ui_link(store["uri"], tracker.parent_id, ui=server))
    page.get_by_text(store["run_name"], exact=True).first.wait_for()
    cell = page.get_by_text("gridworld data", exact=False).first
    cell.wait_for()
    page.screenshot(path=str(ARTIFACTS / "runs_table_datasets.png"))
    cell.click()  # the drawer: both datasets, the digest (the data's input key) and the profile
    page.get_by_text("2 datasets used").wait_for()
    page.get_by_text(store["ikey"], exact=True).first.wait_for()
    page.get_by_text("held-out 0.2", exact=False).first.wait_for()
    page.get_by_text("trajectories:", exact=False).first.wait_for()  # the profile: 10 - 2 held out
    drawer = page.locator("body").inner_text()
    assert "trajectories: 8" in " ".join(drawer.split()), drawer[-500:]
    page.screenshot(path=str(ARTIFACTS / "dataset_drawer.png"))
