"""`pcpg report`: one self-contained HTML page (and a Markdown twin) for one run.

The page is rendered from data, never from text that data could turn into markup: the tables
(CSV) and figures (PNG) found *inside* the run's ``summary`` folder, ``metrics.json`` and
``run.json``, passed to Jinja templates (``pcpg_dist/reporting/templates``) with autoescaping. No path is
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
import shlex
from dataclasses import dataclass
from pathlib import Path

from pcpg_dist.common.errors import ConfigError
from pcpg_dist.common.files import atomic_write_bytes
from pcpg_dist.common.inputs import entries
from pcpg_dist.common.run_folders import check_outside_run
from pcpg_dist.config.experiment import ExperimentConfig
from pcpg_dist.reporting.formatting import accuracy_pivot, fmt, table_of
from pcpg_dist.reporting.jinja import jinja_environment
from pcpg_dist.reporting.paper_comparison import (  # noqa: F401 - paper_numbers/PROTOCOL re-exported
    PAPER_DOMAINS,
    PROTOCOL,
    headline,
    paper_numbers,
    paper_rows,
    plain,
    protocol_differences,
)
from pcpg_dist.reporting.report_data import (
    PaperRow,
    Section,
    figure_of,
    files_in,
    inside,
    read_csv,
    read_metrics,
    read_run,
    reading_once,
)
from pcpg_dist.reporting.run_measures import kept_lengths

# The domain of a config that names none (the config model's own default), read from the config
# model so that no domain is named here.
_DEFAULT_DOMAIN = ExperimentConfig.model_fields["domain"].default


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
        "style_weights",
        "What each cluster weighs (clustering.move_features)",
        "",
        "style_weights.png",
        ("style_weights",),
    ),
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


# A page of hundreds of environment sections is read by nobody and takes the driver seconds per
# environment to build: past this many, the rest are in the run-wide tables (every environment's
# accuracy and clustering), their folders under summary/ and their MLflow runs.
MAX_ENV_SECTIONS = 30


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
    more_envs: list[str]  # environments past MAX_ENV_SECTIONS: in the tables, without sections
    stages: list[list[str]]
    cached: list[str]
    reproduce: str
    provenance: list[tuple[str, str]]
    versions: list[tuple[str, str]]
    machine: list[tuple[str, str]]
    config_json: str


def _summary_sections(summary: Path, by_ref: dict[str, PaperRow]) -> list[Section]:
    """The run-wide sections heading the page: Fig. 4 across environments and the clustering,
    each with its table when the summary has one."""
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
    return top


def _provenance_facts(run: dict, cfg: dict, prov: dict, target: str) -> list[tuple[str, str]]:
    """What reproduces the run: its command, code and lock versions, config hash and seeds."""
    facts = [
        ("command", str(run.get("command", "—"))),
        ("git commit", str(prov.get("git_commit", "—"))),
        ("uv.lock sha256", str(prov.get("uv_lock", "—"))),
        ("config hash", str(run.get("config_hash", "—"))),
        ("base seed", str(cfg.get("seed", "—"))),
        ("repetition seeds", plain(cfg.get("seeds"))),
        ("MLflow parent run", str(run.get("parent_run_id") or "not tracked")),
    ]
    return facts


def build(summary: Path, reproduce_target: str | None = None) -> Report:
    """The page model of a summary folder (reads only files inside it)."""
    with reading_once():
        return _build(Path(summary), reproduce_target)


def _build(summary: Path, reproduce_target: str | None) -> Report:
    run = read_run(summary / "run.json")
    metrics = read_metrics(summary / "metrics.json")
    cfg = run.get("config", {})
    name, domain = (
        str(cfg.get("name", summary.parent.name)),
        str(cfg.get("domain", _DEFAULT_DOMAIN)),
    )
    envs = [d.name for d in entries(summary, "summary folder", dirs=True)]
    paper = paper_rows(domain, metrics, summary, envs)
    by_ref = _by_ref(paper)
    top = _summary_sections(summary, by_ref)
    own_metrics: dict[str, dict[str, float]] = {env: {} for env in envs}
    for key, value in metrics.items():  # "<env>/<metric>": one pass, not one per environment
        env, _, rest = key.partition("/")
        if rest and env in own_metrics:
            own_metrics[env][rest] = value

    def rows_of(env: str) -> dict[str, PaperRow]:
        """This environment's own figures beside the paper's (the run-wide ones head the page)."""
        own = _by_ref(paper_rows(domain, own_metrics[env], summary, [env]))
        # the kept data shares the rollouts' paper figures, not their numbers: its line comes
        # from its own table (this environment's kept lengths)
        kept = PaperRow("", "", own["Figs. 5 and 6"].paper, kept_lengths(summary, [env]))
        return {key: own[ref] for key, _, ref, *_ in ENV_SECTIONS if ref in own} | {
            "subset_length": kept
        }

    shown = envs[:MAX_ENV_SECTIONS]
    env_parts = [(env, *_env_sections(summary, env, rows_of(env))) for env in shown]
    anchors = {sec.anchor for sec in top} | {
        sec.anchor for _, secs, more in env_parts for sec in secs + more
    }
    for row in paper:
        if row.anchor not in anchors:
            row.anchor = ""  # nothing to link to (e.g. no rollouts in this domain)
    stages, cached = _stage_rows(run, len(envs))
    prov = run.get("provenance", {})
    facts = _provenance_facts(run, cfg, prov, reproduce_target or str(summary.resolve().parent))

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
        more_envs=envs[len(shown) :],
        stages=stages,
        cached=cached,
        reproduce=f"pcpg reproduce {shlex.quote(reproduce_target or str(summary.resolve().parent))}",
        provenance=facts,
        versions=pairs(prov.get("versions", {})),
        machine=pairs(prov.get("machine", {})),
        config_json=json.dumps(cfg, indent=1),
    )


# ----------------------------------------------------------------------------- rendering
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
    env = jinja_environment()
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
