"""`pcpg report`: a self-contained HTML page (and Markdown beside it) for one sweep.

It reads a run's ``summary`` folder (locally, or downloaded from MLflow by run id or experiment
name) and shows: the config, seeds, git commit, uv.lock hash, package versions, machine, wall
time per stage, every table and figure, the project's numbers beside the paper's, and the exact
command to rerun.
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

import pandas as pd

from pcpg_dist.dataset import atomic_write_bytes
from pcpg_dist.errors import DataError

KEY_METRICS = ("clustering/accuracy", "clustering/ari", "cross/diagonal_mean",
               "reward_distance/style0", "reward_distance/style1", "reward_distance/style2",
               "reward_distance/style3", "random/reward_distance/style0", "random/reward_distance/style1",
               "random/reward_distance/style2", "random/reward_distance/style3")


def paper_numbers(domain: str | None) -> dict[str, str]:
    """The paper's figures for a domain (none for a domain that is not installed here)."""
    from pcpg_dist.domains import registry
    from pcpg_dist.errors import PcpgError

    try:
        return dict(registry.get(str(domain)).paper_numbers)
    except PcpgError:
        return {}


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise DataError(f"{path}: unreadable ({e})") from None


def _tables(folder: Path) -> list[tuple[str, pd.DataFrame]]:
    out = []
    for csv in sorted(folder.glob("*.csv")):
        try:
            out.append((csv.stem, pd.read_csv(csv)))
        except pd.errors.EmptyDataError:
            continue  # an empty table (e.g. no rollouts for this setting) has nothing to show
        except (OSError, ValueError, pd.errors.ParserError) as e:
            raise DataError(f"{csv}: unreadable table ({e})") from None
    return out


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _md_table(df: pd.DataFrame, max_rows: int = 60) -> str:
    df = df.head(max_rows)
    head = "| " + " | ".join(map(str, df.columns)) + " |"
    sep = "|" + "---|" * len(df.columns)
    rows = ["| " + " | ".join(_fmt(v) for v in r) + " |" for r in df.itertuples(index=False)]
    return "\n".join([head, sep, *rows])


def render(summary: Path, out_dir: Path) -> tuple[Path, Path]:
    """Write ``report.html`` and ``report.md`` (+ figures) into ``out_dir`` from a summary folder."""
    summary, out_dir = Path(summary), Path(out_dir)
    run = _read_json(summary / "run.json")
    metrics = _read_json(summary / "metrics.json")
    cfg = run["config"]
    envs = [d for d in sorted(summary.iterdir()) if d.is_dir()]
    out_dir.mkdir(parents=True, exist_ok=True)
    md = [f"# pcpg-dist report: {cfg['name']}", "",
          f"Rerun: `{run['command']}`", "",
          "## Provenance", "",
          f"- git commit: `{run['provenance']['git_commit']}`",
          f"- uv.lock sha256: `{run['provenance']['uv_lock']}`",
          f"- config hash: `{run['config_hash']}`; base seed {cfg['seed']}; repetition seeds {cfg['seeds']}",
          f"- machine: {run['provenance']['machine']}",
          "- versions: " + ", ".join(f"{k} {v}" for k, v in run['provenance']['versions'].items()),
          f"- MLflow parent run: `{run.get('parent_run_id')}`", "",
          "## Wall time per stage", "",
          _md_table(pd.DataFrame([{"stage": k, "seconds": round(v, 2)} for k, v in run["stage_seconds"].items()])),
          "", "## Results beside the paper", ""]
    paper = paper_numbers(cfg.get("domain"))
    ours = {
        "clustering accuracy": metrics.get("clustering/accuracy"),
        "cross-accuracy diagonal (Table 4)": metrics.get("cross/diagonal_mean"),
        "reward distance, PCPG (Table 3)": " / ".join(
            f"{metrics[f'reward_distance/style{s}']:.2f}" for s in range(4) if f"reward_distance/style{s}" in metrics),
        "reward distance, random (Table 3)": " / ".join(
            f"{metrics[f'random/reward_distance/style{s}']:.2f}" for s in range(4)
            if f"random/reward_distance/style{s}" in metrics),
    }
    rows = [{"measure": k, "paper": paper.get(k, "—"), "pcpg-dist": _fmt(v) if v not in (None, "") else "—"}
            for k, v in ours.items()]
    md += [_md_table(pd.DataFrame(rows)), ""]
    figures: list[tuple[str, Path]] = [("Accuracy vs p (Fig. 4)", summary / "accuracy_vs_p.png")]
    md += ["## Summary tables", ""]
    for name, df in _tables(summary):
        md += [f"### {name}", "", _md_table(df), ""]
    for env in envs:
        md += [f"## Environment {env.name}", ""]
        for name, df in _tables(env):
            md += [f"### {env.name}: {name}", "", _md_table(df), ""]
        figures += [(f"{env.name}: {p.stem}", p) for p in sorted(env.glob("*.png"))]
    md += ["## Figures", ""]
    fig_dir = out_dir / "figures"
    fig_dir.mkdir(exist_ok=True)
    for title, path in figures:
        if path.is_file():
            target = fig_dir / f"{path.parent.name}_{path.name}" if path.parent != summary else fig_dir / path.name
            target.write_bytes(path.read_bytes())
            md += [f"### {title}", "", f"![{title}](figures/{target.name})", ""]
    md += ["## Config", "", "```json", json.dumps(cfg, indent=1), "```", ""]
    md_text = "\n".join(md)
    md_path = out_dir / "report.md"
    atomic_write_bytes(md_path, md_text.encode())
    html_path = out_dir / "report.html"
    atomic_write_bytes(html_path, _to_html(md_text, out_dir).encode())
    return html_path, md_path


def _to_html(md_text: str, base: Path) -> str:
    """A small Markdown-to-HTML pass for what :func:`render` writes; images are inlined (base64)."""
    out, in_code, table = [], False, []

    def flush_table() -> None:
        if table:
            rows = [r.strip("|").split("|") for r in table if not set(r) <= set("|-")]
            head, *body = rows
            out.append("<table><tr>" + "".join(f"<th>{html.escape(c.strip())}</th>" for c in head) + "</tr>"
                       + "".join("<tr>" + "".join(f"<td>{html.escape(c.strip())}</td>" for c in r) + "</tr>"
                                 for r in body) + "</table>")
            table.clear()

    for line in md_text.splitlines():
        if line.startswith("```"):
            flush_table()
            out.append("</pre>" if in_code else "<pre>")
            in_code = not in_code
            continue
        if in_code:
            out.append(html.escape(line))
            continue
        if line.startswith("|"):
            table.append(line)
            continue
        flush_table()
        if line.startswith("#"):
            level = len(line) - len(line.lstrip("#"))
            out.append(f"<h{level}>{html.escape(line[level:].strip())}</h{level}>")
        elif line.startswith("!["):
            alt, src = line[2:].split("](", 1)
            data = base64.b64encode((base / src.rstrip(")")).read_bytes()).decode()
            out.append(f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}" style="max-width:100%">')
        elif line.startswith("- "):
            out.append(f"<li>{html.escape(line[2:])}</li>")
        elif line.strip():
            out.append(f"<p>{html.escape(line)}</p>")
    flush_table()
    style = ("body{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em}"
             "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:2px 6px;"
             "font-size:12px}pre{background:#f6f6f6;padding:0.5em;font-size:11px}")
    return f"<!doctype html><html><head><meta charset='utf-8'><title>pcpg-dist report</title><style>{style}</style></head><body>" + "\n".join(out) + "</body></html>"


def resolve_summary(target: str, tracking_uri: str | None, workdir: Path) -> tuple[Path, str | None]:
    """A summary folder for a local path, an MLflow run id, or an experiment name (latest sweep)."""
    path = Path(target)
    if (path / "run.json").is_file():
        return path, None
    if (path / "summary" / "run.json").is_file():
        return path / "summary", None
    from pcpg_dist.tracking import check_reachable, default_tracking_uri, find_sweep_run

    uri = tracking_uri or default_tracking_uri()
    check_reachable(uri)
    run_id = find_sweep_run(target, uri).info.run_id
    local = Path(workdir) / ".report-cache" / run_id
    import mlflow.artifacts

    got = mlflow.artifacts.download_artifacts(run_id=run_id, artifact_path="summary", dst_path=str(local),
                                              tracking_uri=uri)
    return Path(got), run_id
