"""The HTML report in a real browser: Playwright driving the distribution's Chromium at a laptop's
width (1280 px). Headings, tables and figures must be there, the images must load, and nothing may
overflow sideways. Screenshots go to outputs/test-artifacts/browser (kept by CI).

Chromium comes from the distribution package (`apt-get install -y chromium`, done by .ci/run);
without it the tests skip, saying so.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from pcpg_dist.reporting.report import render
from pcpg_dist.stages import figures

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).parents[1] / "data" / "report_summary"
ARTIFACTS = (
    Path(os.environ.get("PCPG_TEST_ARTIFACTS", ROOT / "outputs" / "test-artifacts")) / "browser"
)
WIDTH = 1280


def chromium_path() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return "/usr/bin/chromium" if Path("/usr/bin/chromium").is_file() else None


@pytest.fixture(scope="module")
def browser():
    exe = chromium_path()
    if exe is None:
        pytest.skip(
            "no Chromium found (install the distribution package: apt-get install -y chromium)"
        )
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=exe, args=["--no-sandbox"])
        yield b
        b.close()


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    summary = tmp_path_factory.mktemp("run") / "tiny" / "summary"
    shutil.copytree(DATA, summary)
    figures.redraw(summary)
    return render(summary, summary.parent / "report")[0]


@pytest.fixture
def page(browser, report):
    pg = browser.new_page(viewport={"width": WIDTH, "height": 900})
    pg.goto(report.as_uri())
    pg.wait_for_load_state("load")
    yield pg
    pg.close()


def test_report_reads_at_laptop_width(page):
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / "report_top.png"))
    page.screenshot(path=str(ARTIFACTS / "report_full.png"), full_page=True)
    assert page.evaluate("document.documentElement.scrollWidth") <= WIDTH
    assert page.evaluate("document.body.scrollWidth") <= WIDTH
    # no element sticks out past the right edge of the viewport
    wide = page.evaluate("""() => [...document.querySelectorAll('body *')]
        .filter(e => e.getBoundingClientRect().right > window.innerWidth + 1
                     && !e.closest('.tablewrap') && e.offsetParent !== null)
        .map(e => e.tagName + '.' + e.className)""")
    assert wide == []


def test_headings_tables_and_figures_are_present(page):
    assert page.locator("h1").inner_text().startswith("pcpg-dist report: ")
    h2 = page.locator("h2").all_inner_texts()
    for heading in (
        "Headline",
        "Beside the paper",
        "Across environments",
        "Environment E1",
        "Wall time per stage and the cache",
        "Reproduce",
        "Provenance",
    ):
        assert heading in h2, heading
    assert h2.index("Headline") == 0  # the headline is the first section
    assert page.locator(".banner").first.is_visible()
    assert page.locator("table:visible").count() >= 10
    images = page.locator("img")
    assert images.count() >= 6
    for i in range(images.count()):  # every figure decoded: the data URI is a real image
        assert images.nth(i).evaluate("img => img.complete && img.naturalWidth > 100"), i
    # folded away until asked for, and readable when opened
    config = page.locator("details", has_text="Full config")
    assert not config.locator("pre").is_visible()
    config.locator("summary").click()
    assert config.locator("pre").is_visible()
    assert page.evaluate("document.documentElement.scrollWidth") <= WIDTH


def test_each_figure_beside_its_table_at_laptop_width(page):
    pairs = page.locator(".pair")
    assert pairs.count() >= 5
    for i in range(pairs.count()):
        fig = pairs.nth(i).locator("figure").bounding_box()
        table = pairs.nth(i).locator("table").first.bounding_box()
        assert fig is not None and table is not None
        assert table["x"] > fig["x"] + fig["width"] - 1  # side by side, not stacked
        assert abs(table["y"] - fig["y"]) < 60
    section = page.locator("#E1-cross")
    section.scroll_into_view_if_needed()
    section.screenshot(path=str(ARTIFACTS / "report_table4.png"))


def test_pdf_export(browser, report, tmp_path):
    from pcpg_dist.cli import main

    assert main(["report", str(report.parent.parent), "--out", str(tmp_path), "--pdf"]) == 0
    pdf = (tmp_path / "report.pdf").read_bytes()
    assert pdf.startswith(b"%PDF-") and pdf.count(b"/Type /Page") - pdf.count(b"/Type /Pages") >= 3


PHONE = 390


def test_protocol_banner_and_sweep_figures_fit_a_phone(browser, report, tmp_path):
    """At 390 px the protocol banner's table wraps inside the page (it was clipped, no scroll cue),
    and the sweep page shows one figure per row."""
    from test_report import make_sweep

    from pcpg_dist.reporting.sweep_page import render_sweep

    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    pg = browser.new_page(viewport={"width": PHONE, "height": 800})
    try:
        pg.goto(report.as_uri())
        pg.wait_for_load_state("load")
        wrap = pg.locator("#protocol .tablewrap")
        assert wrap.evaluate("w => w.scrollWidth <= w.clientWidth + 1")
        box = wrap.locator("table").bounding_box()
        assert box is not None and box["x"] >= 0 and box["x"] + box["width"] <= PHONE
        pg.locator("#protocol").screenshot(path=str(ARTIFACTS / "report_banner_390.png"))
        img = pg.locator("#fig4 img").bounding_box()
        assert img is not None and img["width"] >= PHONE - 60  # Fig. 4 takes the phone's width
        sweep = make_sweep(tmp_path)  # two figures: real PNGs of a report's size
        for name in json.loads((sweep / "sweep.json").read_text())["figures"]:
            (sweep / name).write_bytes(
                (report.parent / "figures" / "accuracy_vs_p.png").read_bytes()
            )
        pg.goto(render_sweep(sweep, sweep).as_uri())
        pg.wait_for_load_state("load")
        figs = pg.locator("figure")
        assert figs.count() == 2
        a, b = figs.nth(0).bounding_box(), figs.nth(1).bounding_box()
        assert (
            b["y"] >= a["y"] + a["height"] - 1 and a["width"] >= PHONE - 60
        )  # stacked, full width
        assert pg.evaluate("document.documentElement.scrollWidth") <= PHONE
        pg.screenshot(path=str(ARTIFACTS / "sweep_390.png"), full_page=True)
    finally:
        pg.close()
