"""What is logged: batched params, metrics and tags, folders without cache bookkeeping, and how a
run's metrics are laid out for the MLflow UI (headline scalars on the parent, curves over p and c,
the rest on each environment's child run), with the run's description and link."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import re
import shutil
import tempfile
import time
from pathlib import Path

from pcpg_dist.tracking.connection import _client, _retry
from pcpg_dist.tracking.tags import BOOKKEEPING, MAX_PARENT_METRICS, METRIC_BATCH, PARAM_BATCH


def _log_params(
    client, run_id: str, params: dict[str, str], have: dict[str, str] | None = None
) -> None:
    """Params not yet on the run (MLflow refuses to change a logged param's value)."""
    from mlflow.entities import Param

    items = [Param(k, str(v)[:6000]) for k, v in sorted(params.items()) if k not in (have or {})]
    for i in range(0, len(items), PARAM_BATCH):
        _retry(client.log_batch, run_id, params=items[i : i + PARAM_BATCH])


def _log_once(
    client,
    run_id: str,
    points: list[tuple[str, float, int]],
    tags: dict[str, str],
    params: dict[str, str] | None = None,
) -> None:
    """Metrics and tags in as few batches as MLflow allows, the tags (the digest) in the last one;
    a few ``params`` of a new run (at most one batch's worth) in the first."""
    from mlflow.entities import Metric, Param, RunTag

    now = int(time.time() * 1000)
    items = [Metric(k, float(v), now, int(step)) for k, v, step in points]
    size = METRIC_BATCH - len(tags) - len(params or {})  # MLflow counts every entity of a batch
    chunks = [items[i : i + size] for i in range(0, len(items), size)] or [[]]
    for i, chunk in enumerate(chunks):
        last = i == len(chunks) - 1
        _retry(
            client.log_batch,
            run_id,
            metrics=chunk,
            params=[Param(k, str(v)) for k, v in (params or {}).items()] if i == 0 else [],
            tags=[RunTag(k, v[:5000]) for k, v in tags.items()] if last else [],
        )


def _log_metrics(client, run_id: str, metrics: dict[str, float]) -> None:
    """Finite scalar metrics at step 0 (`pcpg tune`'s trial and study runs)."""
    _log_once(client, run_id, [(k, v, 0) for k, v in metrics.items() if _finite(v)], {})


def _digest(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _finite(v) -> bool:
    return isinstance(v, int | float) and math.isfinite(v)


def _copy_without_bookkeeping(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns(*BOOKKEEPING))
    return dst


def _log_folder(client, run_id: str, folder: Path, artifact_path: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        clean = _copy_without_bookkeeping(folder, Path(tmp) / "x")
        _retry(client.log_artifacts, run_id, str(clean), artifact_path)


def _std_table(metrics: dict[str, float]) -> str:
    """``metric,value,std`` rows: the std over seeds that the charts leave out."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["metric", "value", "std"])
    for k in sorted(metrics):
        if not k.endswith("/std") and _finite(metrics[k]):
            std = metrics.get(f"{k}/std")
            w.writerow([k, repr(float(metrics[k])), repr(float(std)) if _finite(std) else ""])
    return buf.getvalue()


_AXIS = re.compile(r"^(?P<rest>.+)/(?P<axis>[pc])(?P<x>\d+(?:\.\d+)?(?:e-?\d+)?)$")


def _steps(values: list[float]) -> tuple[dict[float, int], int]:
    """Integer MLflow steps for axis values in [0, 1]: 100 × x unless that merges two values."""
    for scale in (100, 1000, 10000, 100000):
        steps = {x: round(x * scale) for x in values}
        if len(set(steps.values())) == len(steps):
            return steps, scale
    return {x: i for i, x in enumerate(sorted(values))}, 0


def curves(metrics: dict[str, float]) -> tuple[dict[str, dict[float, float]], dict[str, float]]:
    """Split ``.../p<x>`` and ``.../c<x>`` metrics into curves ``{key: {x: value}}`` and scalars."""
    found: dict[str, dict[float, float]] = {}
    scalars: dict[str, float] = {}
    for k, v in metrics.items():
        if k.endswith("/std") or not _finite(v):
            continue
        m = _AXIS.match(k)
        if m:
            found.setdefault(f"{m['rest']}/by_{m['axis']}", {})[float(m["x"])] = float(v)
        else:
            scalars[k] = float(v)
    return found, scalars


def _curve_points(
    named: dict[str, dict[float, float]],
) -> tuple[list[tuple[str, float, int]], dict[str, int]]:
    points, scales = [], {}
    for key, curve in sorted(named.items()):
        steps, scale = _steps(list(curve))
        scales[key] = scale
        points += [(key, curve[x], steps[x]) for x in sorted(curve)]
    return points, scales


# The parent's scalars after PCPG and No Clustering at the largest and smallest p and the
# clustering trio, most important first (the budget keeps the head of the list).
_CLUSTERING = ("clustering/accuracy", "clustering/ceiling", "clustering/gap_to_ceiling")
_HEADLINE = (
    "clustering/ari",
    "clustering/nmi",
    "random/accuracy",
    "majority/accuracy",
    "pcpg/wins_over_baseline",
    "cross/diagonal_mean",
    "correlation/diagonal_mean",
    "corruption/baseline/accuracy",
)
# Curves over an axis: (source prefix, axis) -> chart key; the MLflow UI draws value against step.
PARENT_CURVES = {
    ("pcpg/accuracy", "p"): "accuracy_vs_p/pcpg",
    ("baseline/accuracy", "p"): "accuracy_vs_p/no_clustering",
    ("majority/accuracy", "p"): "accuracy_vs_p/majority_class",
    ("corruption/accuracy", "c"): "accuracy_vs_corruption/pcpg",
    ("corruption/accuracy_true_subsets", "c"): "accuracy_vs_corruption/pcpg_true_subsets",
}
# A headline scalar that can be the very number of a curve or per-p scalar already logged, e.g.
# `corruption/baseline/accuracy` (No Clustering over the corruption study's p, at c = 0) is
# `baseline/accuracy/p1` when that study uses p = 1 only, and `majority/accuracy` is the last point of
# the `accuracy_vs_p/majority_class` curve: each is logged only when it differs.
_MAYBE_SAME = {
    "corruption/baseline/accuracy": "baseline/accuracy",
    "majority/accuracy": "majority/accuracy",
    "random/accuracy": "random/accuracy",
}


def parent_metrics(
    result, timings: bool = True
) -> tuple[list[tuple[str, float, int]], dict[str, int]]:
    """The parent's (key, value, step) points: at most :data:`MAX_PARENT_METRICS` keys.

    Means over environments only (children hold each environment): PCPG and No Clustering at the
    largest and the smallest p, clustering accuracy / ceiling / gap, PCPG and No Clustering at the
    other p, then clustering ARI / NMI, baselines, stage timings (unless ``timings`` is false: a
    sweep's point, whose stages ran batched with the other points') and reward distances while the
    budget lasts; curves over p and over the corruption level as stepped metrics. A headline key
    equal to a per-p value already logged (as a scalar or a curve's point) is left out.
    """
    envs = tuple(f"{e}/" for e in getattr(result, "clustering", {}) or {})
    top = {k: v for k, v in result.metrics.items() if not k.startswith(envs)}
    by_axis, scalars = curves(top)
    named = {
        PARENT_CURVES[(k.rsplit("/by_", 1)[0], k[-1])]: c
        for k, c in by_axis.items()
        if (k.rsplit("/by_", 1)[0], k[-1]) in PARENT_CURVES and len(c) > 1
    }
    points, scales = _curve_points(named)
    ps = sorted(by_axis.get("pcpg/accuracy/by_p", {}), reverse=True)
    ends = list(dict.fromkeys([*ps[:1], *ps[-1:]]))
    per_p = [
        f"{m}/accuracy/p{p:g}"
        for p in [*ends, *(p for p in ps if p not in ends)]
        for m in ("pcpg", "baseline")
    ]
    stage_seconds = getattr(result, "stage_seconds", {}) if timings else {}
    timing = [f"time/{k}_seconds" for k in stage_seconds]
    values = {**top, **{f"time/{k}_seconds": v for k, v in stage_seconds.items()}}
    order = [
        *per_p[:4],
        *_CLUSTERING,
        *per_p[4:],
        *_HEADLINE,
        *timing,
        *sorted(k for k in scalars if k.startswith("reward_distance/")),
    ]
    budget = MAX_PARENT_METRICS - len(named)
    chosen: list[str] = []
    for k in dict.fromkeys(order):
        if len(chosen) == budget:
            break
        if k not in values or not _finite(values[k]):
            continue
        if k in _MAYBE_SAME and any(
            values.get(f"{_MAYBE_SAME[k]}/p{p:g}") == values[k]
            and (
                f"{_MAYBE_SAME[k]}/p{p:g}" in chosen
                or PARENT_CURVES.get((_MAYBE_SAME[k], "p")) in named
            )
            for p in ps
        ):
            continue
        chosen.append(k)
    return [(k, float(values[k]), 0) for k in chosen] + points, scales


def child_metrics(metrics: dict[str, float]) -> tuple[list[tuple[str, float, int]], dict[str, int]]:
    """An environment's detail: scalars as they are, per-p and per-level values as curves, no std."""
    by_axis, scalars = curves(metrics)
    ps = sorted(by_axis.get("pcpg/accuracy/by_p", {}), reverse=True)
    if ps:  # the headline p as scalars too, for the runs table and compare views
        scalars.update(
            {
                f"{m}/accuracy/p{ps[0]:g}": metrics[f"{m}/accuracy/p{ps[0]:g}"]
                for m in ("pcpg", "baseline")
                if _finite(metrics.get(f"{m}/accuracy/p{ps[0]:g}"))
            }
        )
    points, scales = _curve_points(by_axis)
    return [(k, v, 0) for k, v in sorted(scalars.items())] + points, scales


def _fmt(v) -> str:
    return f"{v:.3f}" if _finite(v) else "n/a"


def describe_run(cfg, result, scales: dict[str, int], command: str) -> str:
    """The parent's description (Markdown, shown on the run page): what ran, from where, the result."""
    m = result.metrics
    by_axis, _ = curves({k: v for k, v in m.items() if "/" in k})
    ps = sorted(by_axis.get("pcpg/accuracy/by_p", {}), reverse=True)
    envs = list(getattr(result, "clustering", {}) or [])
    # the result first: the runs table's Description column and the page's summary show the start
    lines = []
    if ps:
        at = [
            f"{_fmt(m.get(f'pcpg/accuracy/p{p:g}'))} vs {_fmt(m.get(f'baseline/accuracy/p{p:g}'))} at p = {p:g}"
            for p in dict.fromkeys([ps[0], ps[-1]])
        ]
        lines.append(
            f"PCPG vs No Clustering accuracy: {'; '.join(at)} (mean over environments; random "
            f"{_fmt(m.get('random/accuracy'))})."
        )
    if _finite(m.get("clustering/accuracy")):
        lines.append(
            f"Clustering accuracy {_fmt(m['clustering/accuracy'])}"
            + (
                f", gap to the supervised ceiling {_fmt(m['clustering/gap_to_ceiling'])}"
                if _finite(m.get("clustering/gap_to_ceiling"))
                else ""
            )
            + "."
        )
    elif _finite(m.get("clustering/silhouette")):
        lines.append(
            f"Clustering silhouette {_fmt(m['clustering/silhouette'])} (no true styles to compare)."
        )
    lines += [
        "",
        f"**{command or 'pcpg run'}** — experiment `{cfg.name}`, domain {getattr(cfg, 'domain', '?')}, "
        f"environments {', '.join(envs) or 'n/a'}, seeds "
        f"{', '.join(map(str, getattr(cfg, 'seeds', []) or []))}, config hash `{cfg.hash()}`.",
    ]
    charts = [
        f"`{k}`: step = {s} × {'p' if k.startswith('accuracy_vs_p') else 'c'}"
        for k, s in sorted(scales.items())
        if s
    ]
    if charts:
        lines += ["", "Curves: " + "; ".join(charts) + "."]
    cached = getattr(result, "cached_stages", None)
    if cached:
        lines.append(f"Stages served from cache: {', '.join(cached)}.")
    lines += [
        "",
        "Children: one run per environment (its tables, figures, models and curves). Std over "
        "seeds: `metrics.csv` artifacts. Tables and figures: `summary/`; the report: `report/report.html`.",
    ]
    return "\n".join(lines)


def ui_link(uri: str, run_id: str, ui: str = "http://127.0.0.1:5000") -> str:
    """The experiment's runs table in the MLflow UI (``ui``: where ``mlflow ui`` serves a local store).

    MLflow 3.17's UI picks GenAI or classic pages from its own workflow switch (saved in the
    browser, GenAI by default), not from the experiment's kind tag: the link names the classic
    workflow, so the first visit already opens on the runs table and the browser keeps it.
    """
    exp_id = _retry(_client(uri).get_run, run_id).info.experiment_id
    base = uri.rstrip("/") if uri.startswith(("http://", "https://")) else ui
    return f"{base}/#/experiments/{exp_id}/runs?workflowType=machine_learning"


def _confidence_tag(metrics: dict) -> dict[str, str]:
    """The label-free confidence in words (``pcpg.confidence``), where it was measured."""
    from pcpg_dist.stages.clustering.confidence import verdict_of

    said = verdict_of(metrics)
    return {} if said.verdict == "not measured" else {"pcpg.confidence": said.line()}
