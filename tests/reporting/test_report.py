"""The HTML report: valid HTML, no Markdown artefacts, headline and paper numbers first, real
table headers, each figure beside its table, the protocol banner, and no file from outside the
run's folder ever embedded.

The fixture is the summary folder of a real tiny GridWorld run (tests/data/report_summary: its
tables, metrics.json and run.json, as `pcpg run` wrote them); the figures are re-drawn from those
tables by :func:`pcpg_dist.stages.figures.redraw`, so the figure code runs here too.
"""

from __future__ import annotations

import base64
import json
import math
import os
import re
import shutil
from pathlib import Path

import html5lib
import numpy as np
import pandas as pd
import pytest

from pcpg_dist.common.errors import DataError
from pcpg_dist.reporting.formatting import table_of
from pcpg_dist.reporting.report import build, render
from pcpg_dist.reporting.sweep_page import render_sweep
from pcpg_dist.stages import figures

DATA = Path(__file__).parents[1] / "data" / "report_summary"
NS = "{http://www.w3.org/1999/xhtml}"


def copy_summary(tmp: Path) -> Path:
    summary = tmp / "tiny" / "summary"
    shutil.copytree(DATA, summary)
    return summary


@pytest.fixture(scope="module")
def summary(tmp_path_factory) -> Path:
    folder = copy_summary(tmp_path_factory.mktemp("run"))
    written = figures.redraw(folder)
    assert len(written) >= 6  # Fig. 4 (summary + E1), Table 4, Fig. 7, Figs. 5-6 (two), Fig. 9
    return folder


@pytest.fixture(scope="module")
def page(summary, tmp_path_factory) -> tuple[str, str]:
    html_path, md_path = render(summary, tmp_path_factory.mktemp("report"))
    return html_path.read_text(), md_path.read_text()


def parse(text: str):
    return html5lib.HTMLParser(strict=True, namespaceHTMLElements=True).parse(text)


def text_of(el) -> str:
    return "".join(el.itertext())


def edit_run(summary: Path, tmp: Path, **changes) -> Path:
    """A copy of the summary folder with run.json fields (or config keys, dotted) changed."""
    folder = tmp / "edited" / "summary"
    shutil.copytree(summary, folder)
    run = json.loads((folder / "run.json").read_text())
    for key, value in changes.items():
        node = run
        *path, last = key.split("__")
        for part in path:
            node = node[part]
        node[last] = value
    (folder / "run.json").write_text(json.dumps(run))
    return folder


def test_report_is_valid_html(page):
    html, _ = page
    parse(html)  # html5lib's strict parser raises on any parse error
    assert html.startswith("<!DOCTYPE html>")


def test_rendered_text_has_no_markdown_artefacts(page):
    body = parse(page[0]).find(f"{NS}body")
    text = text_of(body)
    assert "`" not in text and "|" not in text and "**" not in text
    for line in text.splitlines():
        assert not re.match(r"\s*([-*+]|\d+\.|#+)\s", line), line


def test_headline_comes_first_with_clustering_gap(page, summary):
    html, _ = page
    metrics = json.loads((summary / "metrics.json").read_text())
    order = [
        html.index(s)
        for s in (
            'id="protocol"',
            'id="headline"',
            'id="paper"',
            'id="fig4"',
            'id="env-E1"',
            'id="cache"',
            'id="reproduce"',
            'id="provenance"',
        )
    ]
    assert order == sorted(order)
    headline = html[html.index('id="headline"') : html.index('id="paper"')]
    for key in ("clustering/accuracy", "clustering/ceiling", "clustering/gap_to_ceiling"):
        assert f"{metrics[key]:{'+' if 'gap' in key else ''}.3f}" in headline, key
    assert f"{metrics['pcpg/accuracy/p1']:.3f}" in headline
    assert f"{metrics['baseline/accuracy/p1']:.3f}" in headline


def test_gap_to_the_ceiling_is_explained_as_ceiling_minus_accuracy(page, summary):
    """The metric is ceiling - accuracy (pipeline.py): positive = below the ceiling. The page, its
    Markdown twin and the docs say so, and none says 'accuracy minus the ceiling'."""
    metrics = json.loads((summary / "metrics.json").read_text())
    gap = metrics["clustering/gap_to_ceiling"]
    assert gap == pytest.approx(metrics["clustering/ceiling"] - metrics["clustering/accuracy"])
    html, md = page
    card = parse(html).find(f".//{NS}section[@id='headline']")
    text = " ".join(text_of(card).split())
    assert (
        "the ceiling minus clustering accuracy: positive = below the ceiling, negative = above it"
        in text
    )
    assert "ceiling minus clustering accuracy: positive = below the ceiling" in md
    docs = Path(__file__).resolve().parents[2] / "docs"
    for page_text in [html, md, *(p.read_text() for p in docs.glob("*.md"))]:
        assert "accuracy minus the ceiling" not in page_text
        assert "accuracy minus ceiling" not in page_text


def test_paper_numbers_beside_ours_for_every_table_and_figure(page, summary):
    root = parse(page[0])
    section = next(s for s in root.iter(f"{NS}section") if s.get("id") == "paper")
    rows = [[text_of(td) for td in tr.iter(f"{NS}td")] for tr in section.iter(f"{NS}tr")][1:]
    items = " ".join(r[0] for r in rows)
    for ref in (
        "Table 3",
        "Table 4",
        "Table 5",
        "Fig. 4",
        "Figs. 5 and 6",
        "Fig. 7",
        "Fig. 8",
        "Fig. 9",
    ):
        assert ref in items, ref
    paper = {r[0]: r[1] for r in rows}
    assert paper["Table 3: reward distance to the optimum, PCPG"] == "8.66 / 44.85 / 46.28 / 50.79"
    assert paper["Clustering accuracy"] == "0.66"
    assert all(r[1] and r[2] and r[2] != "—" for r in rows), rows  # ours measured for each item
    anchors = set(re.findall(r'id="([^"]+)"', page[0]))
    assert set(re.findall(r'href="#([^"]+)"', page[0])) <= anchors  # every link lands on a section
    cross = pd.read_csv(summary / "E1" / "cross_accuracy.csv", index_col=0)
    ours = {r[0]: r[2] for r in rows}["Table 4: accuracy of π_k on H_k' (mean over p)"]
    assert ours.startswith(f"diagonal {cross.loc['k0', 'k0']:.2f} / {cross.loc['k1', 'k1']:.2f}")


def test_tables_have_real_headers_and_figures_sit_beside_their_tables(page):
    html, _ = page
    assert "Unnamed" not in html
    root = parse(html)
    env = next(s for s in root.iter(f"{NS}section") if s.get("id") == "env-E1")
    pairs = 0
    for sec in env.iter(f"{NS}section"):
        for div in sec.iter(f"{NS}div"):
            if div.get("class") == "pair":
                assert (
                    len(list(div.iter(f"{NS}img"))) == 1 and len(list(div.iter(f"{NS}table"))) >= 1
                )
                pairs += 1
    assert pairs >= 5  # Fig. 4, Table 4, Fig. 7, Figs. 5-6 (rollouts and kept data), Fig. 9
    heads = [text_of(th) for th in root.iter(f"{NS}th")]
    assert "PCPG ± std" in heads and "H k0" in heads and "environment" in heads


def test_provenance_config_and_machine_are_folded_tables(page, summary):
    root = parse(page[0])
    prov = next(s for s in root.iter(f"{NS}section") if s.get("id") == "provenance")
    folded = {text_of(d.find(f"{NS}summary")): d for d in prov.iter(f"{NS}details")}
    assert set(folded) == {"Run, code and seeds", "Package versions", "Machine", "Full config"}
    assert all(d.get("open") is None for d in folded.values())
    machine = json.loads((summary / "run.json").read_text())["provenance"]["machine"]
    cells = [text_of(c) for c in folded["Machine"].iter() if c.tag in (f"{NS}th", f"{NS}td")]
    assert cells == [x for k, v in machine.items() for x in (k, str(v))]


def test_images_are_inlined_pngs_of_the_summary(page, summary):
    html, _ = page
    uris = re.findall(r'src="data:image/png;base64,([^"]+)"', html)
    pngs = sorted(summary.rglob("*.png"))
    assert len(uris) == len(pngs)
    assert {base64.b64decode(u) for u in uris} == {p.read_bytes() for p in pngs}


def test_no_file_outside_the_run_folder_is_embedded(summary, tmp_path):
    """Issue 18 item 1: a crafted run.json or a symlink in the summary embeds nothing."""
    secret = tmp_path / "secret.png"
    secret.write_bytes(b"\x89PNG\r\n\x1a\n" + b"TOP-SECRET-BYTES" * 8)
    folder = edit_run(
        summary,
        tmp_path,
        command="pcpg run x\n![x](/etc/passwd)\n![y](" + str(secret) + ")\n",
        figures=["/etc/passwd", str(secret)],
        config__name="../../etc/passwd",
    )
    out = tmp_path / "out"
    html_path, md_path = render(folder, out)
    html, md = html_path.read_text(), md_path.read_text()
    for text in (html, md):
        assert "root:" not in text and "TOP-SECRET" not in text
        assert base64.b64encode(secret.read_bytes()).decode()[:40] not in text
    assert len(re.findall("data:image/png;base64,", html)) == len(list(summary.rglob("*.png")))
    assert all(p.read_bytes() != secret.read_bytes() for p in (out / "figures").iterdir())
    assert "/etc/passwd" in html  # the crafted command is shown as text, escaped
    parse(html)
    # a link out of the run, or a special file, is refused in one line (the input policy): never
    # read, never skipped in silence
    planted = [
        (folder / "E1" / "evil.png", secret),
        (folder / "E1" / "passwd.csv", Path("/etc/passwd")),
        (folder / "E2", secret.parent),
    ]
    for link, target in planted:
        link.symlink_to(target)
        with pytest.raises(DataError) as e:
            render(folder, tmp_path / "refused")
        said = str(e.value)
        assert said.startswith("summary ") and f"{link}: a link to {target}, outside" in said
        assert "\n" not in said
        link.unlink()
    os.mkfifo(folder / "E1" / "table.csv")  # was skipped without a word
    with pytest.raises(DataError, match=r"table.csv: a FIFO, not a regular file"):
        render(folder, tmp_path / "refused")


def test_banner_names_every_setting_that_differs_from_the_paper(page, summary, tmp_path):
    html, _ = page
    banner = html[html.index('id="protocol"') : html.index('id="headline"')]
    assert "Not the paper&#39;s protocol" in banner or "Not the paper's protocol" in banner
    for key in (
        "seeds",
        "ranking.ps",
        "bc.epochs",
        "gridworld.environments",
        "pbtg.dataset_per_style",
    ):
        assert f"<td>{key}</td>" in banner, key
    paper = edit_run(
        summary,
        tmp_path,
        config__seeds=[0, 1, 2, 3],
        config__ranking__ps=[1.0, 0.75, 0.5, 0.25, 0.1],
        config__bc__epochs=2000,
        config__bc__hidden_size=5,
        config__bc__hidden_layers=3,
        config__gridworld__environments=["E1", "E2", "E3", "E4", "E5"],
        config__pbtg__trajectories_per_style=8000,
        config__pbtg__dataset_per_style=1000,
        config__pbtg__episodes=20000,
        config__clustering__k=4,
        config__clustering__method="lstm_dec",
    )
    assert build(paper).differences == []
    html = render(paper, tmp_path / "paper")[0].read_text()
    assert "The paper's protocol" in html and "Not the paper" not in html
    aware = build(
        edit_run(summary, tmp_path / "aware", config__ranking__style_margin=1.0)
    )  # not in the paper
    assert [
        d[0] for d in aware.differences if d[0] not in [e[0] for e in build(summary).differences]
    ] == ["ranking.style_margin"]
    other = edit_run(summary, tmp_path / "o", config__domain="trajectories")
    page_other = build(other)
    assert not page_other.in_paper and all("not in the paper" in r.paper for r in page_other.paper)


def test_cache_section_says_which_stages_were_served_from_cache(summary, tmp_path):
    fresh = build(summary)
    assert fresh.cached == []
    cached = build(
        edit_run(summary, tmp_path, computed={"clustering": 0, "train_groups": 0, "evaluations": 0})
    )
    assert cached.cached == ["cluster", "train", "evaluate"]
    html = render(
        edit_run(
            summary, tmp_path / "c", computed={"clustering": 0, "train_groups": 3, "evaluations": 1}
        ),
        tmp_path / "r",
    )[0]
    assert "Served from the cache in this invocation: cluster." in html.read_text()
    # the runner's own record wins: a cached stage keeps the seconds of the run that computed it
    recorded = build(
        edit_run(
            summary,
            tmp_path / "d",
            cached_stages=["generate", "cluster"],
            computed={"data": 0, "clustering": 0, "train_groups": 2, "evaluations": 1},
        )
    )
    assert recorded.cached == ["generate", "cluster"]
    rows = {r[0]: r for r in recorded.stages}
    assert rows["generate"][2:] == [
        "0 data sets generated",
        "cache (seconds of the run that computed it)",
    ]
    assert rows["train"][2:] == ["2 groups of cells trained", "computed"]
    one = build(
        edit_run(
            summary,
            tmp_path / "e",
            computed={"data": 1, "clustering": 1, "train_groups": 1, "evaluations": 1},
        )
    )
    assert [r[2] for r in one.stages][:3] == [
        "1 data set generated",
        "1 of 1 clusterings computed",
        "1 group of cells trained",
    ]
    text = " ".join(html.read_text().split())
    assert "in this invocation: cluster. Every unit" in text  # a space between the two sentences


def test_markdown_twin_escapes_data(summary, tmp_path):
    folder = edit_run(summary, tmp_path, command="pcpg run a|b `x` *y*")
    md = render(folder, tmp_path / "out")[1].read_text()
    assert "pcpg run a|b `x` *y*" in md  # the command block shows it verbatim (indented code)
    assert "| command | pcpg run a\\|b \\`x\\` \\*y\\* |" in md  # escaped inside a table


def test_reproduce_command_is_linked(page, summary):
    html, md = page
    target = str(summary.resolve().parent)
    assert f"pcpg reproduce {target}" in html and f"pcpg reproduce {target}" in md
    assert '<a href="#reproduce">' in html


def test_report_cli_on_a_run_folder(summary, tmp_path):
    from pcpg_dist.cli import main

    assert main(["report", str(summary.parent), "--out", str(tmp_path / "rep")]) == 0
    assert (tmp_path / "rep" / "report.html").stat().st_size > 10_000


def test_figures_share_one_p_convention_and_readable_heatmap_text(tmp_path):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    figures.p_axis(ax, [1.0, 0.1, 0.5, 0.25])
    lo, hi = ax.get_xlim()
    assert lo < 0.1 < 1.0 < hi and list(ax.get_xticks()) == [0.1, 0.25, 0.5, 1.0]
    plt.close(fig)
    cmap = plt.get_cmap("cividis")
    assert figures._text_colour(cmap(0.0)) == "white" and figures._text_colour(cmap(1.0)) == "black"
    rdbu = plt.get_cmap("RdBu_r")
    assert figures._text_colour(rdbu(0.5)) == "black" and figures._text_colour(rdbu(0.0)) == "white"


def test_quick_config_gets_the_banner_and_the_paper_config_does_not():
    from pcpg_dist.config import load_config
    from pcpg_dist.reporting.report import protocol_differences

    root = Path(__file__).resolve().parents[2] / "experiments"
    quick_cfg, paper_cfg = (
        load_config(root / "quick.yaml"),
        load_config(root / "gridworld_paper.yaml"),
    )

    def method_differs(cfg) -> set[str]:  # the paper clusters with lstm_dec; a config may not
        return {"clustering.method"} if cfg.clustering.method != "lstm_dec" else set()

    quick = protocol_differences(quick_cfg.model_dump(mode="json"))
    assert {k for k, _, _ in quick} == {
        "seeds",
        "ranking.ps",
        "bc.epochs",
        "bc.batch_size",  # auto: full batch on GridWorld's cells, but not the paper's setting
        "bc.stop_tol",  # early stopping
        "bc.init",  # auto: from No Clustering where the clustering verdict doubts the styles
        "gridworld.environments",
        "pbtg.trajectories_per_style",
        "pbtg.dataset_per_style",
    } | method_differs(quick_cfg)
    assert ("gridworld.environments", "E1, E3", "E1, E2, E3, E4, E5") in quick
    paper = protocol_differences(paper_cfg.model_dump(mode="json"))
    assert {k for k, _, _ in paper} == method_differs(paper_cfg)


def test_mario_config_lists_every_departure_from_the_paper():
    """experiments/mario.yaml departs from the paper in its state, its minibatches and its
    fine-tuning from the No Clustering agent: the report's protocol table named only the
    clustering method and the network (the audit of the Mario run)."""
    from pcpg_dist.config import load_config
    from pcpg_dist.reporting.report import protocol_differences

    cfg = load_config(Path(__file__).resolve().parents[2] / "experiments" / "mario.yaml")
    found = {
        k: (ours, paper) for k, ours, paper in protocol_differences(cfg.model_dump(mode="json"))
    }
    assert found["bc.init"] == ("no_clustering", "scratch")
    assert found["bc.batch_size"] == ("512", "none (full batch)")
    assert found["mario.event"] == ("onehot", "id") and found["mario.increments"] == (
        "True",
        "False",
    )
    assert "mario.counters" not in found  # the paper's counters are kept
    assert {"clustering.method", "bc.hidden_layers", "bc.hidden_size", "bc.epochs"} <= set(found)
    # a run recorded before these settings existed ran with their defaults
    old = cfg.model_dump(mode="json")
    del old["bc"]["init"], old["mario"]["increments"], old["mario"]["event"]
    found = {k for k, _, _ in protocol_differences(old)}
    assert "bc.init" not in found and "mario.increments" not in found
    assert (
        "mario.event" not in found
    )  # before the setting, the event id was read as a number, as the paper does


def test_a_domain_without_rollouts_or_labels_renders(summary, tmp_path):
    """Mario-like: no rollouts, no corruption study, no true styles; every paper row still says
    what is missing, and the page stays valid."""
    folder = edit_run(summary, tmp_path, config__domain="mario")
    for name in (
        "rollouts",
        "rollout_length",
        "reward_distance",
        "corruption_accuracy",
        "corruption_reward",
        "corruption",
    ):
        for f in (folder / "E1").glob(f"{name}.*"):
            f.unlink()
    metrics = json.loads((folder / "metrics.json").read_text())
    kept = {
        k: v
        for k, v in metrics.items()
        if "reward_distance" not in k and "ceiling" not in k and k != "clustering/accuracy"
    }
    (folder / "metrics.json").write_text(json.dumps(kept))
    page_model = build(folder)
    ours = {r.item.split(":")[0]: r.ours for r in page_model.paper}
    assert (
        ours["Table 3"] == "— (no rollouts)"
        and ours["Fig. 9"] == "—"
        and ours["Fig. 8"].startswith("—")
    )
    assert page_model.headline["accuracy"] is None and page_model.headline["compared"] == 2
    html = render(folder, tmp_path / "out")[0].read_text()
    parse(html)
    assert 'id="E1-corruption"' not in html and 'href="#E1-corruption"' not in html
    anchors = set(re.findall(r'id="([^"]+)"', html))
    assert set(re.findall(r'href="#([^"]+)"', html)) <= anchors and "E1-cross" in anchors


def test_kept_length_line_comes_from_the_data_and_table3_says_why_it_is_absent(summary, tmp_path):
    """The kept-trajectory section's "this run" line gives the data's kept lengths (its own table,
    subset_length), not the rollouts' (it showed the rollout line, and "— (no rollouts)" above a full
    table without them); Table 3 without distances says why: no rollouts, or rollouts but no
    reward-distance hooks (it said "no rollouts" beside rollouts)."""

    def lengths(path: Path) -> str:
        every = pd.read_csv(path)

        def by_p(d):  # kept data (with n): over the kept trajectories; rollouts: over the agents
            if "n" not in d:
                return d.groupby("p")["mean"].mean()
            return {p: float(np.average(g["mean"], weights=g["n"])) for p, g in d.groupby("p")}

        d = every[every.method == "pcpg"]
        pc, nc, top = by_p(d), by_p(every[every.method == "nc"]), d[d.p == d.p.max()]["mean"]
        ps = sorted(pc.keys())
        return (
            f"PCPG mean length {pc[ps[0]]:.1f} at p={ps[0]:g} to {pc[ps[-1]]:.1f} at "
            f"p={ps[-1]:g}; styles at p={d.p.max():g} from {top.min():.1f} to {top.max():.1f}; "
            f"No Clustering {nc[ps[0]]:.1f} to {nc[ps[-1]]:.1f}"
        )

    def lines(folder: Path) -> tuple[dict[str, str], dict[str, str]]:
        model = build(folder)
        sections = {s.anchor: s.ours for _, secs, _ in model.envs for s in secs}
        return sections, {r.item: r.ours for r in model.paper}

    kept, rolled = (
        lengths(summary / "E1" / "subset_length.csv"),
        lengths(summary / "E1" / "rollout_length.csv"),
    )
    assert kept != rolled
    # at p = 1 the clusters together keep what No Clustering keeps: one figure for both
    assert kept.split(" to ")[1].split(" at p=1")[0] == kept.rsplit(" to ", 1)[1]
    sections, _ = lines(summary)
    assert sections["E1-subset_length"] == kept and sections["E1-rollout_length"] == rolled
    md = render(summary, tmp_path / "with")[1].read_text()
    kept_part = md[md.index("Kept-trajectory length vs p") :]
    assert (
        kept.split(";")[0] in kept_part.split("\n###")[0] and rolled.split(";")[0] not in kept_part
    )

    table3 = "Table 3: reward distance to the optimum, PCPG"
    no_hooks = tamper_metrics(summary, tmp_path / "hooks", lambda k: "reward_distance" not in k)
    (no_hooks / "E1" / "reward_distance.csv").unlink()
    sections, paper = lines(no_hooks)  # rollouts ran, but the domain measures no reward distance
    assert paper[table3] == "— (no reward-distance hooks for this domain)"
    for f in (no_hooks / "E1").glob("rollout*"):
        f.unlink()
    sections, paper = lines(no_hooks)  # no rollouts at all (a data-only domain)
    assert paper[table3] == "— (no rollouts)"
    assert "E1-rollout_length" not in sections and sections["E1-subset_length"] == kept


def tamper_metrics(summary: Path, tmp: Path, keep) -> Path:
    """A copy of ``summary`` with only the metrics whose name ``keep`` accepts."""
    folder = tmp / "summary"
    shutil.copytree(summary, folder)
    metrics = json.loads((folder / "metrics.json").read_text())
    (folder / "metrics.json").write_text(json.dumps({k: v for k, v in metrics.items() if keep(k)}))
    return folder


# ----------------------------------------------------------------------------- bad summaries
ACCURACY_HEAD = "method,p,mean,std,seeds\n"
TAMPERED = {  # case: (file in the summary, its new text, what the one error line must say)
    "accuracy_repeated_row": (
        "E1/accuracy.csv",
        ACCURACY_HEAD + "pcpg,1.0,0.5,0,1\npcpg,1.0,0.6,0,1\n",
        "accuracy.csv: line 3 repeats the row for method 'pcpg', p 1.0",
    ),
    "accuracy_without_std": (
        "E1/accuracy.csv",
        "method,p,mean,seeds\npcpg,1.0,0.5,1\n",
        "accuracy.csv: no column 'std'",
    ),
    "accuracy_p_text": (
        "E1/accuracy.csv",
        ACCURACY_HEAD + "pcpg,abc,0.5,0,1\n",
        "accuracy.csv: column 'p', line 2: 'abc' is not a number",
    ),
    "cross_accuracy_text": (
        "E1/cross_accuracy.csv",
        ",k0,k1\nk0,abc,0.5\nk1,0.1,0.2\n",
        "cross_accuracy.csv: column 'k0', line 2: 'abc' is not a number",
    ),
    "cluster_style_text": (
        "E1/cluster_style.csv",
        "k,style\n0,abc\n",
        "cluster_style.csv: column 'style', line 2: 'abc' is not a number",
    ),
    "cluster_style_half": (
        "E1/cluster_style.csv",
        "k,style\n0,0.5\n1,1\n",
        "cluster_style.csv: column 'style' must hold whole numbers",
    ),
    "cluster_style_repeated": (
        "E1/cluster_style.csv",
        "k,style\n0,0\n0,1\n",
        "cluster_style.csv: line 3 repeats the row for k 0",
    ),
    "computed_text": ("run.json", {"computed": {"data": "x"}}, "run.json: computed 'data' is 'x'"),
    "computed_overflow": (
        "run.json",
        {"computed": {"data": math.inf}},
        "run.json: computed 'data' is inf",
    ),
    "stage_seconds_list": (
        "run.json",
        {"stage_seconds": [1, 2]},
        "run.json: 'stage_seconds' is [1, 2]",
    ),
    "metric_text": (
        "metrics.json",
        {"pcpg/accuracy/p1": "x"},
        "metrics.json: metric 'pcpg/accuracy/p1' is 'x'",
    ),
    "metric_list": (
        "metrics.json",
        {"pcpg/accuracy/p1": [1]},
        "metrics.json: metric 'pcpg/accuracy/p1' is [1]",
    ),
    "metric_p_text": (
        "metrics.json",
        {"pcpg/accuracy/pabc": 0.5},
        "metrics.json: metric 'pcpg/accuracy/pabc'",
    ),
    "run_json_nested": (
        "run.json",
        "[" * 100_000 + "]" * 100_000,
        "run.json: unreadable (maximum recursion",
    ),
}


def tamper(summary: Path, tmp: Path, file: str, content) -> Path:
    """A copy of ``summary`` with ``file`` replaced (text as is; a dict merged into the JSON file)."""
    folder = tmp / "tampered" / "summary"
    shutil.copytree(summary, folder)
    path = folder / file
    if isinstance(
        content, dict
    ):  # JSON has no infinity: a number beyond float's range reads as one
        content = json.dumps(json.loads(path.read_text()) | content).replace("Infinity", "1e400")
    path.write_text(content)
    return folder


@pytest.mark.parametrize("case", sorted(TAMPERED))
def test_tampered_summary_files_are_one_line_data_errors(case, tmp_path, capsys):
    """A tampered table or JSON file in the summary: exit 2, one line naming the file and what is
    wrong, and no report folder (was a pandas, int() or json traceback, exit 1)."""
    from pcpg_dist.cli import main
    from pcpg_dist.common.errors import DataError

    file, content, says = TAMPERED[case]
    folder = tamper(DATA, tmp_path, file, content)
    out = tmp_path / "out"
    assert main(["report", str(folder.parent), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"pcpg: error: {folder / file}: "), err
    assert says in err[0]
    assert not out.exists()
    with pytest.raises(DataError, match=re.escape(says)):  # the library raises it too
        build(folder)


def test_report_out_inside_the_summary_is_refused(summary, tmp_path, capsys):
    """`--out RUN/summary` (or below it) would make the next report read its figures/ as an
    environment: refused, one line naming --out, nothing written into the summary."""
    from pcpg_dist.cli import main

    folder = tmp_path / "run" / "summary"
    shutil.copytree(summary, folder)
    before = sorted(p.relative_to(folder) for p in folder.rglob("*"))
    for out in (folder, folder / "report", folder / "E1" / ".." / "x"):
        assert main(["report", str(folder.parent), "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(
            f"pcpg: error: --out {out}: inside the run's summary folder"
        )
    assert sorted(p.relative_to(folder) for p in folder.rglob("*")) == before
    assert main(["report", str(folder.parent)]) == 0  # the default, RUN/report, is outside it
    assert (folder.parent / "report" / "report.html").is_file()


def test_report_of_a_mistyped_run_creates_no_mlflow_store(tmp_path, monkeypatch, capsys):
    """Not a folder, and no sqlite store in the current folder: one line, and no mlflow.db made
    (opening the default store created a 1 MB file)."""
    from pcpg_dist.cli import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    assert main(["report", "nosuchrun"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"pcpg: error: 'nosuchrun' is neither a run's output folder nor an MLflow run: no such "
        f"folder, and no MLflow store at sqlite:///{tmp_path.resolve() / 'mlflow.db'}"
    ]
    assert list(tmp_path.iterdir()) == []


def test_one_number_format_per_column():
    """Counts as integers, lengths and rewards to 1 decimal, fractions to 3; a std takes its mean's
    decimals; No Clustering's k of -1 is a dash. Was: "7.000 ± 0.000" beside "11 ± 0.000", "99.737 ±
    0.263" beside "137.2 ± 1.665", counts as "2.000"."""
    lengths = pd.DataFrame(
        {
            "method": ["nc", "pcpg", "pcpg"],
            "k": [-1, 0, 3],
            "p": [1.0, 1.0, 0.5],
            "mean": [7.0, 11.0, 13.943],
            "std": [0.0, 0.0, 2.435],
            "n": [80, 176, 88],
        }
    )
    t = table_of(lengths, "subset_length")
    assert t.rows == [
        ["No Clustering", "—", "1", "7.0 ± 0.0", "80"],
        ["PCPG", "0", "1", "11.0 ± 0.0", "176"],
        ["PCPG", "3", "0.5", "13.9 ± 2.4", "88"],
    ]
    reward = pd.DataFrame(
        {
            "c": [0.0, 0.5],
            "k": [0, 0],
            "R1": [100.0, 99.737],
            "R2": [150.0, 137.2],
            "R1_std": [0.0, 0.263],
            "R2_std": [0.0, 1.665],
        }
    )
    assert table_of(reward, "corruption_reward").rows == [
        ["0", "0", "100.0 ± 0.0", "150.0 ± 0.0"],
        ["0.5", "0", "99.7 ± 0.3", "137.2 ± 1.7"],
    ]
    acc = pd.DataFrame(
        {"p": [1.0], "pcpg": [1.0], "pcpg_std": [0.0], "random": [0.25], "seeds": [2]}
    )
    assert table_of(acc, "accuracy").rows == [["1", "1.000 ± 0.000", "0.250", "2"]]


def test_clustering_table_leads_with_accuracy_ceiling_and_gap(page):
    body = parse(page[0]).find(f"{NS}body")
    table = body.find(f".//{NS}section[@id='clustering']//{NS}table")
    labels = [text_of(tr.find(f"{NS}td")) for tr in table.find(f"{NS}tbody")]
    assert labels[:3] == ["accuracy", "ceiling", "gap to ceiling (ceiling − accuracy)"], labels
    cells = [text_of(td) for tr in table.find(f"{NS}tbody") for td in tr.findall(f"{NS}td")[1:]]
    assert "1.000" not in cells and all(re.fullmatch(r"-?\d+(\.\d{3})?|—", c) for c in cells), cells


def make_sweep(root: Path) -> Path:
    """A sweep folder as `pcpg sweep` writes it: sweep.json, summary.csv (columns in its order:
    alphabetical metrics, std beside), one figure, and two points with their own reports."""
    folder = root / "sw" / "sweep"
    folder.mkdir(parents=True)
    png = (DATA.parent / "report_summary").glob("**/*.png")
    figure = next(png, None)
    data = (
        figure.read_bytes()
        if figure
        else base64.b64decode(
            "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNk+M9QDwADhgGAWjR9awAAAABJRU5ErkJggg=="
        )
    )
    names = ["pcpg_accuracy_p0.5__vs__clustering.k.png", "pcpg_lead_p0.5__vs__clustering.k.png"]
    for name in names:
        (folder / name).write_bytes(data)
    (folder / "sweep.json").write_text(
        json.dumps(
            {
                "format": 1,
                "name": "sw",
                "description": "Sweep of sw over clustering.k",
                "axes": {"clustering.k": [3, 4]},
                "fixed": {"bc.epochs": 200},
                "points": 2,
                "figures": names,
            }
        )
    )
    (folder / "summary.csv").write_text(
        "clustering.k,baseline/accuracy/p0.5,baseline/accuracy/p0.5/std,clustering/accuracy,clustering/ceiling,"
        "clustering/gap_to_ceiling,pcpg/accuracy/p0.5,pcpg/accuracy/p0.5/std,pcpg_lead/p0.5,point\n"
        "3,0.6338,0.0309793,0.739062,0.979688,0.240625,0.99127,0.000793651,0.357439,k=3-aaaa\n"
        "4,0.546,0.034606,0.971875,0.979688,0.0078125,0.992098,0.00068306,0.446146,k=4-bbbb\n"
    )
    for point in ("k=3-aaaa", "k=4-bbbb"):
        (folder / "points" / point / "report").mkdir(parents=True)
        (folder / "points" / point / "report" / "report.html").write_text(f"<p>{point}</p>")
        (folder / "points" / point / "summary").mkdir()
        (folder / "points" / point / "summary" / "run.json").write_text(
            json.dumps(
                {
                    "command": f"pcpg sweep sw.yaml clustering.k=3,4 [point clustering.k={point[2]}]",
                    "provenance": {"git_commit": "abc123", "uv_lock": "f00d"},
                    "config": {"seed": 0, "seeds": [0, 1]},
                }
            )
        )
    return folder


def test_sweep_page_reads_like_the_run_report(tmp_path):
    """Axes first, then PCPG, No Clustering and the lead, then clustering accuracy, ceiling and gap,
    as mean ± std to 3 decimals; a headline; each point's report linked (relative: the links work
    once the folder is moved); figures with headings and captions, one per row on a phone."""
    folder = make_sweep(tmp_path)
    body = parse(render_sweep(folder, folder).read_text()).find(f"{NS}body")
    table = body.find(f".//{NS}section[@id='points']//{NS}table")
    headers = [text_of(th) for th in table.iter(f"{NS}th")]
    assert headers == [
        "clustering.k",
        "PCPG, p=0.5 ± std",
        "No Clustering, p=0.5 ± std",
        "PCPG lead over No Clustering, p=0.5",
        "clustering accuracy",
        "supervised ceiling",
        "gap to the ceiling (ceiling − accuracy)",
        "report",
    ]
    rows = [[text_of(td) for td in tr.findall(f"{NS}td")] for tr in table.find(f"{NS}tbody")]
    assert rows[0] == [
        "3",
        "0.991 ± 0.001",
        "0.634 ± 0.031",
        "+0.357",
        "0.739",
        "0.980",
        "+0.241",
        "report",
    ]
    assert rows[1][2] == "0.546 ± 0.035"
    headline = " ".join(text_of(body.find(f".//{NS}section[@id='headline']")).split())
    assert "Best point" in headline and "clustering.k=4" in headline and "+0.446" in headline
    moved = tmp_path / "moved"
    shutil.move(str(folder.parent), str(moved))
    for a in table.iter(f"{NS}a"):
        href = a.get("href")
        assert not href.startswith(("/", "file:")) and (moved / "sweep" / href).is_file(), href
    figs = body.findall(f".//{NS}figure")
    assert [text_of(f.find(f"{NS}h4")) for f in figs] == [
        "PCPG, p=0.5 vs clustering.k",
        "PCPG lead over No Clustering, p=0.5 vs clustering.k",
    ]
    # as the figures drew them: the lead has no std over seeds, so no bars (every caption said bars)
    captions = [text_of(f.find(f"{NS}figcaption")) for f in figs]
    assert "; error bars: std over seeds, mean over environments." in captions[0]
    assert (
        "; no error bars: no std over seeds." in captions[1]
        and "error bars: std" not in captions[1]
    )
    assert "pcpg sweep sw.yaml clustering.k=3,4" in text_of(
        body.find(f".//{NS}section[@id='provenance']")
    )
    assert (
        "minmax(min(100%"
        in parse(render_sweep(moved / "sweep", tmp_path / "out").read_text())
        .find(f".//{NS}style")
        .text
    )  # one figure per row where two do not fit
    # rendered elsewhere (pcpg report SWEEP --out DIR): the links still reach the points
    page = (tmp_path / "out" / "report.html").read_text()
    for href in re.findall(r'href="([^"#]+)"', page):
        assert (tmp_path / "out" / href).resolve().is_file(), href


def test_fig4_across_environments_plots_the_headline_mean_large_enough(summary, tmp_path):
    """One panel of the mean over environments (the numbers the headline quotes), drawn at a size
    whose tick labels stay readable at half a laptop's width; was three small panels per row."""
    from matplotlib.figure import Figure

    from pcpg_dist.stages.figures import accuracy_figure

    seen = []
    real = Figure.savefig

    def keep(fig, path, *a, **k):
        seen.append(fig)
        return real(fig, path, *a, **k)

    acc = pd.read_csv(summary / "accuracy_vs_p.csv")
    acc = pd.concat([acc, acc.assign(env="E9", pcpg=acc.pcpg - 0.1)], ignore_index=True)
    Figure.savefig = keep
    try:
        accuracy_figure(acc, tmp_path / "fig4.png")
    finally:
        Figure.savefig = real
    (fig,) = seen
    axes = [ax for ax in fig.axes if ax.get_visible()]
    assert len(axes) == 1 and fig.get_figwidth() <= 6.5
    pcpg = next(
        line
        for line in axes[0].get_lines()
        if line.get_color() == "#0072B2" and line.get_lw() >= 1.5
    )
    want = acc.groupby("p").pcpg.mean()
    assert list(pcpg.get_ydata()) == pytest.approx(list(want.sort_index()))
    assert min(t.get_fontsize() for t in axes[0].get_xticklabels()) >= 10


def add_env(summary: Path, name: str, order: list[int], shift: float) -> None:
    """A second environment: E1's files with its clusters renumbered (cluster i of ``name`` is E1's
    cluster ``order[i]``) and its own metrics (E1's plus ``shift``)."""
    shutil.copytree(summary / "E1", summary / name)
    cross = pd.read_csv(summary / "E1" / "cross_accuracy.csv", index_col=0)
    names = [f"k{i}" for i in order]
    moved = cross.loc[names, names]
    moved.index = moved.columns = [f"k{i}" for i in range(len(order))]
    moved.to_csv(summary / name / "cross_accuracy.csv")
    pd.DataFrame({"k": range(len(order)), "style": order}).to_csv(
        summary / name / "cluster_style.csv", index=False
    )
    metrics = json.loads((summary / "metrics.json").read_text())
    metrics.update(
        {f"{name}/{k[3:]}": v + shift for k, v in list(metrics.items()) if k.startswith("E1/")}
    )
    (summary / "metrics.json").write_text(json.dumps(metrics))


def test_each_environment_section_shows_its_own_figures_and_table4_is_in_style_order(
    summary, tmp_path
):
    """An environment's "this run" lines quoted the run-wide figures; Table 4's line averaged the
    environments' matrices by cluster number, which is arbitrary in each environment."""
    from pcpg_dist.reporting.run_measures import cross_summary

    folder = copy_summary(tmp_path)
    pd.DataFrame({"k": range(4), "style": range(4)}).to_csv(
        folder / "E1" / "cluster_style.csv", index=False
    )
    add_env(folder, "E2", [2, 0, 3, 1], shift=10.0)
    model = build(folder)
    lines = {s.anchor: s.ours for _, secs, _ in model.envs for s in secs}
    metrics = json.loads((folder / "metrics.json").read_text())
    for env in ("E1", "E2"):
        random = " / ".join(
            f"{metrics[f'{env}/random/reward_distance/style{s}']:.2f}" for s in range(4)
        )
        assert lines[f"{env}-reward"].endswith(f"random {random}"), (env, lines[f"{env}-reward"])
    # E2 is E1 renumbered: in style order both read as E1, and so does their mean
    e1 = cross_summary(folder, ["E1"])
    assert e1.startswith("diagonal 0.96 / 0.92 / 0.92 / 0.92; off-diagonal 0.06 to 0.76")
    assert cross_summary(folder, ["E2"]) == e1 == cross_summary(folder, ["E1", "E2"])
    assert e1.endswith("(styles R1 to R4: clusters matched to styles)")  # says which order it is in
    assert lines["E2-cross"] == e1
    # without a one-to-one match the matrices are not averaged cell by cell
    pd.DataFrame({"k": range(4), "style": [0, 0, 1, 2]}).to_csv(
        folder / "E2" / "cluster_style.csv", index=False
    )
    assert cross_summary(folder, ["E2"]).endswith("(by cluster: not matched to styles one to one)")
    assert cross_summary(folder, ["E1", "E2"]).startswith(
        "diagonal mean 0.93, the row maximum in 8 of 8 rows"
    )


def test_fig7_line_counts_the_rows_where_a_model_correlates_most_with_its_own_subset(
    summary, tmp_path
):
    """The paper's claim is per row; the line gave only the mean diagonal beside it, which held
    where one model correlated more with another cluster's subset than with its own."""
    from pcpg_dist.reporting.paper_comparison import paper_rows

    folder = copy_summary(tmp_path)
    path = folder / "E1" / "correlation.csv"
    corr = pd.read_csv(path, index_col=0)
    assert (corr.to_numpy().argmax(axis=1) == np.arange(4)).all()
    fig7 = "Fig. 7: model vs subset correlation"
    metrics = json.loads((folder / "metrics.json").read_text())
    row = {r.item: r.ours for r in paper_rows("gridworld", metrics, folder, ["E1"])}[fig7]
    assert row.endswith("; the diagonal is the row maximum in 4 of 4 rows")
    corr.iloc[1, 3] = corr.iloc[1, 1] + 0.1  # model k1 now correlates most with k3's subset
    corr.iloc[2, 2] = np.nan  # a constant column has no correlation: not a row maximum
    corr.to_csv(path)
    row = {r.item: r.ours for r in paper_rows("gridworld", metrics, folder, ["E1"])}[fig7]
    assert row.startswith("mean diagonal correlation ") and row.endswith(
        "the row maximum in 2 of 4 rows"
    )


def test_table3_keeps_each_style_in_its_column_and_table5_spreads_within_an_environment(
    summary, tmp_path
):
    from pcpg_dist.reporting.paper_comparison import paper_rows

    folder = copy_summary(tmp_path)
    add_env(folder, "E2", [0, 1, 2, 3], shift=0.0)
    reward = pd.read_csv(folder / "E2" / "corruption_reward.csv")
    rcols = [c for c in reward.columns if c.startswith("R") and not c.endswith("_std")]
    reward[rcols] += 1000.0 * (np.arange(len(reward)) % 3)[:, None]  # E2's clusters far apart
    reward.to_csv(folder / "E2" / "corruption_reward.csv", index=False)
    metrics = {"reward_distance/style0": 1.0, "reward_distance/style2": 3.0}  # style 1: no cluster
    rows = {r.item: r.ours for r in paper_rows("gridworld", metrics, folder, ["E1", "E2"])}
    assert rows["Table 3: reward distance to the optimum, PCPG"] == "1.00 / — / 3.00"
    spread = {}
    for env in ("E1", "E2"):
        d = pd.read_csv(folder / env / "corruption_reward.csv")
        spread[env] = d.groupby("c")[rcols].std(ddof=0).mean(axis=1)
    want = (spread["E1"] + spread["E2"]) / 2
    assert rows["Table 5: subset rewards under label corruption"].endswith(
        " ; ".join(f"c={c:g}: {v:.1f}" for c, v in want.items())
    )


def test_past_thirty_environments_the_page_lists_the_rest_and_reads_each_table_once(
    summary, tmp_path, monkeypatch
):
    """A run of many environments: sections for the first MAX_ENV_SECTIONS, the rest named in
    one section that says where their tables are. Building the page reads each summary table once (it used to read them twice)."""
    from pcpg_dist.reporting import report, report_data

    folder = copy_summary(tmp_path)
    for i in range(report.MAX_ENV_SECTIONS + 4):
        add_env(folder, f"X{i:02d}", [0, 1, 2, 3], shift=0.0)
    reads: list[str] = []
    real = report_data._read_checked

    def counted(path):
        reads.append(str(path))
        return real(path)

    monkeypatch.setattr(report_data, "_read_checked", counted)
    html_path, md_path = render(folder, tmp_path / "report")
    assert len(reads) == len(set(reads)) > 0
    model = build(folder)
    envs = sorted(["E1", *(f"X{i:02d}" for i in range(report.MAX_ENV_SECTIONS + 4))])
    assert [env for env, _, _ in model.envs] == envs[: report.MAX_ENV_SECTIONS]
    assert model.more_envs == envs[report.MAX_ENV_SECTIONS :] == [f"X{i}" for i in range(29, 34)]
    doc = parse(html_path.read_text())
    more = doc.find(f".//{NS}section[@id='more-envs']")
    assert more is not None and "X29, X30, X31, X32, X33" in text_of(more)
    assert "35 environments" in text_of(doc.find(f".//{NS}header"))
    assert "## 5 more environments" in md_path.read_text()


def test_what_each_cluster_weighs_is_a_figure_and_a_table_beside_it(summary, tmp_path):
    """A clustering by the moves' features (choice_mix) writes ``style_weights``: the page shows
    it as a section of its own, its figure drawn from the table, the feature names escaped."""
    folder = edit_run(summary, tmp_path)
    table = pd.DataFrame(
        {"feature": ["takes", "<b>check</b>", "pawn push"], "k0": [1.5, -0.2, 0.1],
         "k1": [-0.3, 2.0, 0.0]}
    )  # fmt: skip
    table.to_csv(folder / "E1" / "style_weights.csv", index=False)
    assert folder / "E1" / "style_weights.png" in figures.redraw(folder)
    html = render(folder, tmp_path / "out")[0].read_text()
    parse(html)
    section = html.split('id="E1-style_weights"')[1].split('id="E1-')[0]  # to the next one
    assert "What each cluster weighs" in section and "data:image/png;base64," in section
    assert "pawn push" in section and "&lt;b&gt;check&lt;/b&gt;" in section
    assert "<b>check</b>" not in html
