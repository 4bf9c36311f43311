"""`pcpg report`: one self-contained HTML page (and a Markdown twin) for one run.

The page is rendered from data, never from text that data could turn into markup: the tables
(CSV) and figures (PNG) found *inside* the run's ``summary`` folder, ``metrics.json`` and
``run.json``, passed to Jinja templates (``pcpg_dist/templates``) with autoescaping. No path is
ever taken from a file's content: a figure is a regular PNG file below the summary folder (no
symlink, no ``..``), so a crafted ``run.json`` cannot pull another file into the report.

What the page shows, in reading order: a banner when the config is not the paper's protocol, the
headline (PCPG vs No Clustering, clustering accuracy and its gap to the supervised ceiling), the
paper's numbers beside ours for every table and figure the paper has, then each figure next to
its table, which stages were served from the cache, the command that reproduces the run, and the
config and environment folded away. :func:`build` makes the page model (plain dataclasses, every
value already formatted); the templates only lay it out.
"""

from __future__ import annotations

import json
import math
import shlex
from dataclasses import dataclass
from pathlib import Path

from pcpg_dist.common.errors import ConfigError, first_line
from pcpg_dist.common.run_folders import check_outside_run
from pcpg_dist.dataset import atomic_write_bytes
from pcpg_dist.reporting.paper_comparison import (  # noqa: F401 - paper_numbers/PROTOCOL re-exported
    PAPER_DOMAINS,
    PROTOCOL,
    headline,
    kept_lengths,
    paper_numbers,
    paper_rows,
    plain,
    protocol_differences,
)
from pcpg_dist.reporting.report_data import (
    PaperRow,
    Section,
    accuracy_pivot,
    figure_of,
    files_in,
    fmt,
    inside,
    read_csv,
    read_metrics,
    read_run,
    table_of,
)

# ----------------------------------------------------------------------------- sections
#: per-environment sections: (key, title, paper reference, figure, tables)
ENV_SECTIONS = (
    ("accuracy", "Accuracy vs p", "Fig. 4", "accuracy_vs_p.png", ("accuracy",)),
    (
        "cross",
        "Accuracy of π_k on H_k' (mean over p)",
        "Table 4",
        "cross_accuracy.png",
        ("cross_accuracy",),
    ),
    ("correlation", "Model vs subset correlation", "Fig. 7", "correlation.png", ("correlation",)),
    ("reward", "Reward distance to the optimum", "Table 3", None, ("reward_distance",)),
    (
        "rollout_length",
        "Rollout length vs p",
        "Figs. 5 and 6",
        "rollout_length.png",
        ("rollout_length",),
    ),
    (
        "subset_length",
        "Kept-trajectory length vs p (from the data)",
        "Figs. 5 and 6",
        "subset_length.png",
        ("subset_length",),
    ),
    ("rollouts", "One rollout per style", "Fig. 8", "rollouts.png", ()),
    (
        "corruption",
        "Accuracy vs label corruption",
        "Fig. 9",
        "corruption.png",
        ("corruption_accuracy",),
    ),
    (
        "corruption_reward",
        "Subset rewards under label corruption",
        "Table 5",
        None,
        ("corruption_reward",),
    ),
)


def _env_sections(
    summary: Path, env: str, rows: dict[str, PaperRow]
) -> tuple[list[Section], list[Section]]:
    """An environment's sections (``rows``: the paper's and this run's line of each, by section key)
    and what it has beyond them."""
    folder = summary / env
    csvs = {p.stem: p for p in files_in(folder, summary, ".csv")}
    pngs = {p.name: p for p in files_in(folder, summary, ".png")}
    used_csv, used_png, sections = set(), set(), []
    for key, title, ref, png, tables in ENV_SECTIONS:
        sec = Section(f"{env}-{key}", title, ref)
        if png and png in pngs:
            sec.figure = figure_of(pngs[png], summary, f"{env}: {title}")
            used_png.add(png)
        for name in tables:
            if name not in csvs:
                continue
            used_csv.update({name, f"{name}_std"})
            df = read_csv(csvs[name])
            if df is None or not len(df):
                continue
            if name == "accuracy" and {"method", "p", "mean"} <= set(df.columns):
                df = accuracy_pivot(df)
            std = read_csv(csvs[f"{name}_std"]) if f"{name}_std" in csvs else None
            sec.tables.append(table_of(df, name, f"{env}/{name}.csv", std))
        if sec.figure is None and not sec.tables:
            continue
        paper = rows.get(key)
        if paper is not None:
            sec.paper_says, sec.ours = paper.paper, paper.ours
        sections.append(sec)
    more = []  # what the domain adds beyond the paper's items, and the raw per-seed tables
    for name, path in pngs.items():
        if name not in used_png:
            more.append(
                Section(
                    f"{env}-{path.stem}-figure",
                    path.stem.replace("_", " "),
                    figure=figure_of(path, summary, f"{env}: {path.stem}"),
                )
            )
    for name, path in csvs.items():
        if name not in used_csv:
            df = read_csv(path)
            if df is not None and len(df):
                more.append(
                    Section(
                        f"{env}-{name}",
                        name.replace("_", " "),
                        tables=[table_of(df, name, f"{env}/{name}.csv")],
                    )
                )
    return sections, more


def _ref_key(item: str) -> str:
    return item.split(":")[0].strip()


def _by_ref(rows: list[PaperRow]) -> dict[str, PaperRow]:
    """``paper_rows`` by the paper's item ("Fig. 4", "Table 4", ...); Table 3's two rows (PCPG,
    random) as one."""
    out = {_ref_key(r.item): r for r in rows}
    out["Table 3"] = PaperRow(
        "Table 3",
        "",
        *(
            f"{a}; random {b}"
            for a, b in zip(
                (rows[2].paper, rows[2].ours), (rows[3].paper, rows[3].ours), strict=True
            )
        ),
    )
    return out


def _stage_rows(run: dict, n_envs: int) -> tuple[list[list[str]], list[str]]:
    """(stage, seconds, work done, source) rows and the stages served wholly from the cache
    (``run`` as :func:`read_run` checked it)."""
    computed, seconds = run.get("computed", {}), run.get("stage_seconds", {})
    work = {
        "generate": ("data", ("data set generated", "data sets generated")),
        "cluster": ("clustering", (f"of {n_envs} clusterings computed",) * 2),
        "train": ("train_groups", ("group of cells trained", "groups of cells trained")),
        "evaluate": ("evaluations", (f"of {n_envs} evaluations computed",) * 2),
    }
    listed = run.get("cached_stages")
    if listed is not None:  # the runner's own record (it keeps a cached stage's first timing)
        cached = list(listed)
    else:
        cached = [s for s, (key, _) in work.items() if key in computed and not computed[key]]
    rows = []
    for stage, secs in seconds.items():
        key, (one, many) = work.get(stage, ("", ("", "")))
        done = f"{computed[key]} {one if computed[key] == 1 else many}" if key in computed else "—"
        if stage in cached:
            source = (
                "cache (seconds of the run that computed it)" if listed is not None else "cache"
            )
        else:
            source = "computed"
        rows.append([stage, fmt(float(secs), 1), done, source])
    return rows, cached


@dataclass
class Report:
    """Everything the templates show, already formatted."""

    title: str
    name: str
    domain: str
    run: dict
    cfg: dict
    in_paper: bool
    differences: list[tuple[str, str, str]]
    headline: dict
    paper: list[PaperRow]
    summary_sections: list[Section]
    envs: list[tuple[str, list[Section], list[Section]]]
    stages: list[list[str]]
    cached: list[str]
    reproduce: str
    provenance: list[tuple[str, str]]
    versions: list[tuple[str, str]]
    machine: list[tuple[str, str]]
    config_json: str


def build(summary: Path, reproduce_target: str | None = None) -> Report:
    """The page model of a summary folder (reads only files inside it)."""
    summary = Path(summary)
    run = read_run(summary / "run.json")
    metrics = read_metrics(summary / "metrics.json")
    cfg = run.get("config", {})
    name, domain = str(cfg.get("name", summary.parent.name)), str(cfg.get("domain", "gridworld"))
    envs = [d.name for d in sorted(summary.iterdir()) if d.is_dir() and not d.is_symlink()]
    paper = paper_rows(domain, metrics, summary, envs)
    by_ref = _by_ref(paper)
    top: list[Section] = []
    fig4 = Section(
        "fig4",
        "Accuracy vs p across environments",
        "Fig. 4",
        by_ref["Fig. 4"].paper,
        by_ref["Fig. 4"].ours,
        figure_of(summary / "accuracy_vs_p.png", summary, "accuracy vs p"),
    )
    clus = Section(
        "clustering",
        "Clustering (Step A)",
        "",
        by_ref["Clustering accuracy"].paper,
        by_ref["Clustering accuracy"].ours,
    )
    for sec, stem in ((fig4, "accuracy_vs_p"), (clus, "clustering")):
        path = summary / f"{stem}.csv"
        if inside(path, summary) and (df := read_csv(path)) is not None and len(df):
            sec.tables.append(table_of(df, stem, f"{stem}.csv"))
        top.append(sec)

    def rows_of(env: str) -> dict[str, PaperRow]:
        """This environment's own figures beside the paper's (the run-wide ones head the page)."""
        own = _by_ref(
            paper_rows(
                domain,
                {k[len(env) + 1 :]: v for k, v in metrics.items() if k.startswith(f"{env}/")},
                summary,
                [env],
            )
        )
        # the kept data shares the rollouts' paper figures, not their numbers: its line comes
        # from its own table (this environment's kept lengths)
        kept = PaperRow("", "", own["Figs. 5 and 6"].paper, kept_lengths(summary, [env]))
        return {key: own[ref] for key, _, ref, *_ in ENV_SECTIONS if ref in own} | {
            "subset_length": kept
        }

    env_parts = [(env, *_env_sections(summary, env, rows_of(env))) for env in envs]
    anchors = {sec.anchor for sec in top} | {
        sec.anchor for _, secs, more in env_parts for sec in secs + more
    }
    for row in paper:
        if row.anchor not in anchors:
            row.anchor = ""  # nothing to link to (e.g. no rollouts in this domain)
    stages, cached = _stage_rows(run, len(envs))
    prov = run.get("provenance", {})
    target = reproduce_target or str(summary.resolve().parent)
    facts = [
        ("command", str(run.get("command", "—"))),
        ("git commit", str(prov.get("git_commit", "—"))),
        ("uv.lock sha256", str(prov.get("uv_lock", "—"))),
        ("config hash", str(run.get("config_hash", "—"))),
        ("base seed", str(cfg.get("seed", "—"))),
        ("repetition seeds", plain(cfg.get("seeds"))),
        ("MLflow parent run", str(run.get("parent_run_id") or "not tracked")),
    ]

    def pairs(d) -> list[tuple[str, str]]:
        return (
            [(str(k), str(v)) for k, v in d.items()] if isinstance(d, dict) else [("value", str(d))]
        )

    return Report(
        title=f"pcpg-dist report: {name}",
        name=name,
        domain=domain,
        run=run,
        cfg=cfg,
        in_paper=domain in PAPER_DOMAINS,
        differences=protocol_differences(cfg),
        headline=headline(metrics),
        paper=paper,
        summary_sections=top,
        envs=env_parts,
        stages=stages,
        cached=cached,
        reproduce=f"pcpg reproduce {shlex.quote(target)}",
        provenance=facts,
        versions=pairs(prov.get("versions", {})),
        machine=pairs(prov.get("machine", {})),
        config_json=json.dumps(cfg, indent=1),
    )


# ----------------------------------------------------------------------------- rendering
def _md_escape(value) -> str:
    """Text for a Markdown table cell or line: markup characters escaped, no line breaks."""
    text = str(value).replace("\r", " ").replace("\n", " ")
    for ch in "\\`*_[]<>|#!":
        text = text.replace(ch, "\\" + ch)
    return text


def _environment():
    from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape

    env = Environment(
        loader=PackageLoader("pcpg_dist", "templates"),
        undefined=StrictUndefined,
        autoescape=select_autoescape(["html.j2"]),
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters["md"] = _md_escape
    return env


def check_out_dir(summary: Path, out_dir: Path) -> None:
    """The report goes outside the summary folder: every folder in there is read as an environment."""
    summary_at, out_at = Path(summary).resolve(), Path(out_dir).resolve()
    if out_at == summary_at or summary_at in out_at.parents:
        raise ConfigError(
            f"--out {out_dir}: inside the run's summary folder {summary}, where the next report "
            f"would read its figures as an environment; choose a folder outside it "
            f"(default: {Path(summary).parent / 'report'})"
        )
    check_outside_run(out_dir)


def render(summary: Path, out_dir: Path, reproduce_target: str | None = None) -> tuple[Path, Path]:
    """Write ``report.html`` (self-contained) and ``report.md`` (+ ``figures/``) into ``out_dir``.

    Everything is read and rendered before the first byte is written, and each file is written
    atomically: a bad summary leaves ``out_dir`` as it was.
    """
    summary, out_dir = Path(summary), Path(out_dir)
    check_out_dir(summary, out_dir)
    report = build(summary, reproduce_target)
    env = _environment()
    html = env.get_template("report.html.j2").render(r=report).encode()
    md = env.get_template("report.md.j2").render(r=report).encode()
    figures = {}  # only files the page model took from inside the summary
    for sections in [report.summary_sections] + [s + m for _, s, m in report.envs]:
        for sec in sections:
            if sec.figure is not None:
                figures[sec.figure.file.replace("/", "_")] = (
                    summary / sec.figure.file
                ).read_bytes()
    (out_dir / "figures").mkdir(parents=True, exist_ok=True)
    for name, data in figures.items():
        atomic_write_bytes(out_dir / "figures" / name, data)
    html_path, md_path = out_dir / "report.html", out_dir / "report.md"
    atomic_write_bytes(html_path, html)
    atomic_write_bytes(md_path, md)
    return html_path, md_path


def chromium() -> str | None:
    """The Chromium executable (the distribution's package), or None."""
    import shutil

    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


def export_pdf(html_path: Path, pdf_path: Path | None = None, timeout: float = 120.0) -> Path:
    """Print the report to PDF with a headless Chromium; folded sections stay folded."""
    import os
    import subprocess

    from pcpg_dist.common.errors import ServiceError

    html_path = Path(html_path).resolve()
    pdf_path = Path(pdf_path or html_path.with_suffix(".pdf")).resolve()
    exe = chromium()
    if exe is None:
        raise ServiceError(
            "--pdf needs Chromium (apt-get install -y chromium); or open report.html in a "
            "browser and print it"
        )
    cmd = [
        exe,
        "--headless",
        "--disable-gpu",
        "--no-pdf-header-footer",
        f"--print-to-pdf={pdf_path}",
        html_path.as_uri(),
    ]
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        cmd.insert(1, "--no-sandbox")  # Chromium refuses to run as root with its sandbox
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.TimeoutExpired) as e:
        raise ServiceError(f"--pdf: Chromium failed ({e})") from None
    if not pdf_path.is_file() or pdf_path.read_bytes()[:5] != b"%PDF-":
        tail = (done.stderr.strip().splitlines() or ["no output"])[-1][:300]
        raise ServiceError(f"--pdf: Chromium wrote no PDF (exit {done.returncode}: {tail})")
    return pdf_path


@dataclass(frozen=True)
class Source:
    """What `pcpg report` renders: a run's ``summary`` folder, or a sweep's folder (``sweep.json``,
    ``summary.csv``, figures), and the MLflow run id it came from (``None`` for a local folder)."""

    kind: str  # "run" or "sweep"
    folder: Path
    run_id: str | None = None


def is_sweep_folder(path: Path) -> bool:
    """A `pcpg sweep` output folder (``<workdir>/<name>/sweep``), also one written before sweep.json."""
    return (path / "sweep.json").is_file() or (
        (path / "summary.csv").is_file() and (path / "points").is_dir()
    )


def resolve(target: str, tracking_uri: str | None, workdir: Path) -> Source:
    """A local run folder (``runs/NAME`` or its ``summary``), a sweep folder (``runs/NAME/sweep``), an
    MLflow run id (a run, a sweep or one point of a sweep) or an experiment name (its newest
    top-level run: a `pcpg run` or a `pcpg sweep`); MLflow artifacts are downloaded under
    ``workdir/.report-cache/<run id>``."""
    path = Path(target)
    if (path / "run.json").is_file():
        return Source("run", path)
    if (path / "summary" / "run.json").is_file():
        return Source("run", path / "summary")
    if is_sweep_folder(path):
        return Source("sweep", path)
    from pcpg_dist.tracking import find_run

    run, uri = find_run(target, tracking_uri)
    run_id = run.info.run_id
    local = Path(workdir) / ".report-cache" / run_id

    if run.data.tags.get("pcpg.role") == "sweep":  # the sweep's files lie at its run's root
        got = _download(run_id, None, local / "sweep", uri)
        return Source("sweep", Path(got), run_id)
    return Source("run", Path(_download(run_id, "summary", local, uri)), run_id)


def _download(run_id: str, artifact_path: str | None, dst: Path, uri: str) -> str:
    import mlflow.artifacts
    from mlflow.exceptions import MlflowException

    from pcpg_dist.common.errors import ServiceError

    dst.mkdir(parents=True, exist_ok=True)
    try:
        return mlflow.artifacts.download_artifacts(
            run_id=run_id, artifact_path=artifact_path, dst_path=str(dst), tracking_uri=uri
        )
    except (MlflowException, OSError) as e:
        first = first_line(e)
        what = f"no {artifact_path!r} artifacts" if artifact_path else "no artifacts"
        raise ServiceError(
            f"MLflow run {run_id} at {uri} has {what} to report ({first}); is it a pcpg run "
            "that finished?"
        ) from None


def sweep_refusal(target: str, tracking_uri: str | None, command: str) -> None:
    """Raise a one-line :class:`ConfigError` when ``target`` is a whole sweep (its folder, or its MLflow
    run): ``command`` works on one run, so name one of the sweep's points instead."""
    path = Path(target)
    if (
        not (path / "run.json").is_file()
        and not (path / "summary" / "run.json").is_file()
        and is_sweep_folder(path)
    ):
        points = (
            sorted(p.name for p in (path / "points").iterdir() if p.is_dir())
            if (path / "points").is_dir()
            else []
        )
        example = f", e.g. {path / 'points' / points[0]}" if points else ""
        raise ConfigError(
            f"{target} is the folder of a whole pcpg sweep; {command} takes one run: give one of "
            f"its points' folders ({path / 'points'}/<point>{example}) or a point's MLflow run id"
        )
    if path.exists():
        return
    from pcpg_dist.tracking import find_run, sweep_points_of

    run, uri = find_run(target, tracking_uri)
    if run.data.tags.get("pcpg.role") != "sweep":
        return
    points = sweep_points_of(run.info.run_id, uri)
    example = f", e.g. {points[0].info.run_id} ({points[0].info.run_name})" if points else ""
    raise ConfigError(
        f"{target} is the MLflow run of a whole pcpg sweep ({run.info.run_name}); {command} takes "
        f"one run: give one of the sweep's point runs{example} or a point's folder "
        "(<workdir>/<name>/sweep/points/<point>)"
    )


def resolve_summary(
    target: str, tracking_uri: str | None, workdir: Path, command: str = "pcpg reproduce"
) -> tuple[Path, str | None]:
    """The ``summary`` folder of one run (see :func:`resolve`); a whole sweep is refused in one line."""
    sweep_refusal(target, tracking_uri, command)
    source = resolve(target, tracking_uri, workdir)
    return source.folder, source.run_id


# ----------------------------------------------------------------------------- a sweep's page
SWEEP_STD = "/std"


def sweep_metric_label(key: str) -> str:
    """A readable name for a sweep's headline metric (``pcpg/accuracy/p0.5`` -> ``PCPG, p=0.5``)."""
    fixed = {
        "clustering/accuracy": "clustering accuracy",
        "clustering/ceiling": "supervised ceiling",
        "clustering/gap_to_ceiling": "gap to the ceiling (ceiling − accuracy)",
        "cross/diagonal_mean": "cross-accuracy diagonal (Table 4)",
    }
    if key in fixed:
        return fixed[key]
    for prefix, label in (
        ("pcpg/accuracy/p", "PCPG"),
        ("baseline/accuracy/p", "No Clustering"),
        ("pcpg_lead/p", "PCPG lead over No Clustering"),
    ):
        if key.startswith(prefix):
            return f"{label}, p={key.removeprefix(prefix)}"
    return key.replace("_", " ")


def _sweep_columns(keys: list[str]) -> list[str]:
    """The metric columns in reading order: per p (largest first) PCPG, No Clustering and the lead,
    then clustering accuracy, ceiling, gap and the cross-accuracy diagonal, then anything else."""
    ps = sorted(
        {k.removeprefix("pcpg/accuracy/p") for k in keys if k.startswith("pcpg/accuracy/p")},
        key=lambda p: -float(p) if p.replace(".", "", 1).isdigit() else 0,
    )
    order = [
        k for p in ps for k in (f"pcpg/accuracy/p{p}", f"baseline/accuracy/p{p}", f"pcpg_lead/p{p}")
    ]
    order += [
        "clustering/accuracy",
        "clustering/ceiling",
        "clustering/gap_to_ceiling",
        "cross/diagonal_mean",
    ]
    shown = [k for k in order if k in keys]
    return shown + [k for k in keys if k not in shown]


def _sweep_cell(row: dict, key: str) -> str:
    v = row.get(key)
    if not isinstance(v, float):
        return "—"
    signed = key.startswith("pcpg_lead/") or key == "clustering/gap_to_ceiling"
    text = "—" if math.isnan(v) else f"{v:+.3f}" if signed else f"{v:.3f}"
    sd = row.get(key + SWEEP_STD)
    return (
        f"{text} ± {sd:.3f}"
        if isinstance(sd, float) and not math.isnan(sd) and text != "—"
        else text
    )


@dataclass
class SweepPage:
    title: str
    description: str
    headline: list[str]
    headers: list[str]
    rows: list[dict]  # {"cells": [...], "report": relative link or "", "point": folder name}
    figures: list[tuple[str, list[dict]]]  # (axis, [{"title", "caption", "uri", "name"}])
    command: str
    provenance: list[tuple[str, str]]
    fixed: list[tuple[str, str]]


def build_sweep(folder: Path, out_dir: Path) -> SweepPage:
    """The page model of a sweep folder (``sweep.json``, ``summary.csv``, the figures it names and
    each point's ``report/report.html`` and ``summary/run.json`` below ``points/``)."""
    import base64
    import os
    import re

    from pcpg_dist.common.errors import DataError
    from pcpg_dist.orchestration.sweep import SWEEP_JSON, _read_rows, read_sweep_record
    from pcpg_dist.reporting.report_data import MAX_IMAGE_BYTES

    folder, out_dir = Path(folder), Path(out_dir)
    record = read_sweep_record(folder)
    axes = record["axes"]
    table = folder / "summary.csv"
    if not inside(table, folder):
        raise DataError(f"{folder}: no summary.csv (a regular file) beside {SWEEP_JSON}")
    rows = _read_rows(table, axes)
    keys = [
        k
        for k in dict.fromkeys(k for r in rows for k in r)
        if k not in axes and k != "point" and not k.endswith(SWEEP_STD)
    ]
    metrics = _sweep_columns(keys)
    points_dir = folder / "points"
    # a point's folder is one listed in points/ (never a path read from summary.csv)
    listed = (
        {p.name: p for p in points_dir.iterdir() if p.is_dir() and not p.is_symlink()}
        if points_dir.is_dir() and not points_dir.is_symlink()
        else {}
    )
    link_base = Path(os.path.relpath(folder.resolve(), out_dir.resolve()))
    shown, run = [], None
    for r in rows:
        point = listed.get(str(r.get("point", "")))
        report = ""
        if point is not None and inside(point / "report" / "report.html", folder):
            report = (link_base / "points" / point.name / "report" / "report.html").as_posix()
        if point is not None and run is None and inside(point / "summary" / "run.json", folder):
            try:
                run = read_run(point / "summary" / "run.json")
            except DataError:
                run = None
        shown.append(
            {
                "cells": [plain(r.get(a, "")) for a in axes] + [_sweep_cell(r, k) for k in metrics],
                "report": report,
                "point": str(r.get("point", "")),
            }
        )
    headers = [
        *axes,
        *(
            sweep_metric_label(k) + (" ± std" if any(k + SWEEP_STD in r for r in rows) else "")
            for k in metrics
        ),
    ]

    def num(r, k):
        v = r.get(k)
        return v if isinstance(v, float) and not math.isnan(v) else None

    ps = [k.removeprefix("pcpg/accuracy/p") for k in metrics if k.startswith("pcpg/accuracy/p")]
    headline_lines = []
    scored = [
        (sum(num(r, f"pcpg/accuracy/p{p}") or 0.0 for p in ps) / max(len(ps), 1), i)
        for i, r in enumerate(rows)
        if ps and all(num(r, f"pcpg/accuracy/p{p}") is not None for p in ps)
    ]
    if scored:
        _, best = max(scored, key=lambda t: (t[0], -t[1]))  # the first of equals
        r = rows[best]
        where = ", ".join(f"{a}={plain(r.get(a))}" for a in axes)
        parts = []
        for p in ps:
            lead = num(r, f"pcpg_lead/p{p}")
            parts.append(
                f"{num(r, f'pcpg/accuracy/p{p}'):.3f} at p={p}"
                + (f" (lead over No Clustering {lead:+.3f})" if lead is not None else "")
            )
        headline_lines.append(
            f"Best point (highest PCPG accuracy, mean over p): {where}: PCPG "
            + "; ".join(parts)
            + "."
        )
    leads = [num(r, f"pcpg_lead/p{p}") for r in rows for p in ps]
    leads = [v for v in leads if v is not None]
    if leads:
        headline_lines.append(
            f"PCPG is more accurate than No Clustering at {sum(v > 0 for v in leads)} of "
            f"{len(leads)} (point, p) pairs; its lead ranges from {min(leads):+.3f} to "
            f"{max(leads):+.3f}."
        )
    acc = [
        (num(r, "clustering/accuracy"), i)
        for i, r in enumerate(rows)
        if num(r, "clustering/accuracy") is not None
    ]
    if acc:
        v, i = max(acc, key=lambda t: (t[0], -t[1]))
        gap = num(rows[i], "clustering/gap_to_ceiling")
        headline_lines.append(
            f"Best clustering accuracy {v:.3f} at "
            + ", ".join(f"{a}={plain(rows[i].get(a))}" for a in axes)
            + (
                f" (gap to the ceiling {gap:+.3f}: the ceiling minus clustering accuracy)"
                if gap is not None
                else ""
            )
            + "."
        )

    safe = {re.sub(r"[^A-Za-z0-9._-]+", "_", k): k for k in keys}
    safe_axes = {re.sub(r"[^A-Za-z0-9._-]+", "_", a): a for a in axes}
    by_axis: dict[str, list[dict]] = {a: [] for a in axes}
    order = {k: i for i, k in enumerate(metrics)}
    for name in record["figures"]:
        path = folder / name
        if not inside(path, folder) or path.stat().st_size > MAX_IMAGE_BYTES:
            raise DataError(
                f"{folder}: figure {name} named in {SWEEP_JSON} is not a regular PNG file there "
                f"(at most {MAX_IMAGE_BYTES} bytes)"
            )
        stem = name.removesuffix(".png")
        metric_part, _, axis_part = stem.partition("__vs__")
        metric, axis = safe.get(metric_part, metric_part), safe_axes.get(axis_part, axis_part)
        others = [a for a in axes if a != axis]
        # as the figure drew them (sweep.draw_sweep): bars only where a point has a std over seeds
        bars = any((num(r, metric + SWEEP_STD) or 0.0) > 0 for r in rows)
        caption = (
            f"{sweep_metric_label(metric)} against {axis}"
            + (f"; one line per value of {', '.join(others)}" if others else "")
            + (
                "; error bars: std over seeds, mean over environments."
                if bars
                else "; no error bars: no std over seeds."
            )
        )
        by_axis.setdefault(axis, []).append(
            {
                "title": f"{sweep_metric_label(metric)} vs {axis}",
                "caption": caption,
                "name": name,
                "uri": "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode(),
                "order": order.get(metric, len(order)),
            }
        )
    figures = [(a, sorted(f, key=lambda f: f["order"])) for a, f in by_axis.items() if f]
    command = "—"
    provenance: list[tuple[str, str]] = []
    if run is not None:
        command = re.sub(r"\s*\[point [^\]]*\]$", "", str(run.get("command", "—")))
        prov = run.get("provenance", {})
        provenance = [
            ("git commit", str(prov.get("git_commit", "—"))),
            ("uv.lock sha256", str(prov.get("uv_lock", "—"))),
            ("base seed", str(run.get("config", {}).get("seed", "—"))),
            ("repetition seeds", plain(run.get("config", {}).get("seeds"))),
        ]
    provenance.append(("points", str(len(rows))))
    return SweepPage(
        title=f"Sweep: {record['name']}",
        description=record["description"],
        headline=headline_lines,
        headers=headers,
        rows=shown,
        figures=figures,
        command=command,
        provenance=provenance,
        fixed=[
            (str(k), json.dumps(v) if isinstance(v, dict) else plain(v))
            for k, v in record["fixed"].items()
        ],
    )


def render_sweep(folder: Path, out_dir: Path) -> Path:
    """Write the sweep's ``report.html`` (self-contained; links to each point's own report are
    relative, so they work when the sweep folder is moved) into ``out_dir``."""
    page = build_sweep(folder, out_dir)
    html = _environment().get_template("sweep.html.j2").render(s=page).encode()
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    path = Path(out_dir) / "report.html"
    atomic_write_bytes(path, html)
    return path
