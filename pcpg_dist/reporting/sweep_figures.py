"""A sweep's figures: one PNG per headline metric against each swept axis, one line per value of
the other axes, with readable names for the axes and metrics."""

from __future__ import annotations

import io
import math
import re
from pathlib import Path
from typing import Any

from pcpg_dist.common.files import atomic_write_bytes
from pcpg_dist.common.point_labels import axis_text, short_keys
from pcpg_dist.reporting.sweep_files import STD


def _numeric(values: list) -> bool:
    return all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)


# Readable names for the figures (the raw key stays in brackets on the axis).
AXIS_LABELS = {
    "pbtg.noise_max": "largest per-trajectory action noise",
    "pbtg.noise_min": "smallest action noise",
    "clustering.k": "k (clusters)",
    "clustering.method": "clustering method",
    "bc.epochs": "BC epochs",
    "bc.hidden_size": "BC hidden size",
    "bc.lr": "BC learning rate",
    "pbtg.trajectories_per_style": "trajectories per style",
    "pbtg.dataset_per_style": "dataset trajectories per style",
}


_METRIC_LABELS = {
    "clustering/accuracy": "clustering accuracy",
    "clustering/ceiling": "supervised ceiling",
    "clustering/gap_to_ceiling": "gap to the supervised ceiling",
    "clustering/stability": "clustering stability (no labels)",
    "cross/diagonal_mean": "cross-accuracy diagonal (mean)",
}


_PER_P = {
    "pcpg/accuracy/p": "PCPG accuracy",
    "baseline/accuracy/p": "No Clustering accuracy",
    "pcpg_lead/p": "PCPG lead over No Clustering",
}


def _readable(metric: str) -> str:
    """``pcpg/accuracy/p0.5`` -> "PCPG accuracy at p = 0.5"; a key without a name stays as it is."""
    for prefix, name in _PER_P.items():
        if metric.startswith(prefix):
            return f"{name} at p = {metric.removeprefix(prefix)}"
    return _METRIC_LABELS.get(metric, metric)


def _axis_label(axis: str) -> str:
    return f"{AXIS_LABELS[axis]} ({axis})" if axis in AXIS_LABELS else axis


PALETTE = (
    "#0072B2",
    "#E69F00",
    "#009E73",
    "#CC79A7",
    "#56B4E9",
    "#D55E00",
    "#F0E442",
    "#000000",
)
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")


def draw_sweep(out: Path, axes: dict[str, list], rows: list[dict[str, Any]]) -> list[Path]:
    """One PNG per headline metric against each axis: one line per value of the other axes, error
    bars the std over seeds (each environment's, averaged over environments: the ``/std`` keys),
    where the metric has one (clustering is fitted once per point and PCPG's lead is a difference
    of means: none); the title says which. Ticks only at the swept values (a numeric axis keeps its spacing). Lines
    are drawn side by side (a small horizontal offset, a marker each), so equal lines stay visible,
    and the legend names the ones that are identical."""
    import matplotlib

    matplotlib.use("Agg")

    metrics = [
        k
        for k in dict.fromkeys(k for r in rows for k in r)
        if k not in axes and k != "point" and not k.endswith(STD)
    ]
    short = short_keys(list(axes))
    paths = []
    for axis in axes:
        for metric in metrics:
            paths.append(_draw_one(out, axes, axis, metric, rows, short))
    return paths


def _lines(
    rows: list[dict[str, Any]], axis: str, values: list, xs: list, others: list[str], metric: str
) -> dict[tuple, list]:
    """One line per value of the other axes: its (x, mean, std) points in the axis's order."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(axis_text(r[o]) for o in others), []).append(r)
    lines: dict[tuple, list] = {}
    for key, members in groups.items():
        by_x = {axis_text(r[axis]): r for r in members}
        pts = [
            (x, by_x[axis_text(v)]) for x, v in zip(xs, values, strict=True) if axis_text(v) in by_x
        ]
        lines[key] = [(x, r.get(metric, math.nan), r.get(metric + STD, 0.0)) for x, r in pts]
    return lines


def _line_label(key: tuple, others: list[str], short: dict[str, str], twins: list) -> str | None:
    """A line's legend entry: the other axes' values, and the lines identical to it."""
    label = ", ".join(f"{short[o]}={k}" for o, k in zip(others, key, strict=True)) or None
    if label and twins:
        label += (
            " (same as "
            + "; ".join(
                ", ".join(f"{short[o]}={k}" for o, k in zip(others, twin, strict=True))
                for twin in twins
            )
            + ")"
        )
    return label


def _draw_one(
    out: Path,
    axes: dict[str, list],
    axis: str,
    metric: str,
    rows: list[dict[str, Any]],
    short: dict[str, str],
) -> Path:
    """The PNG of one metric against one axis, written atomically; returns its path."""
    import matplotlib.pyplot as plt

    values = axes[axis]
    others = [a for a in axes if a != axis]
    xs = [float(v) for v in values] if _numeric(values) else list(range(len(values)))
    gaps = [b - a for a, b in zip(sorted(xs), sorted(xs)[1:], strict=False) if b > a]
    width = min(gaps) if gaps else 1.0
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=110)
    lines = _lines(rows, axis, values, xs, others, metric)
    same = {
        key: [other for other in lines if other != key and lines[other] == lines[key]]
        for key in lines
    }
    has_std = False
    n = len(lines)
    for gi, (key, pts) in enumerate(lines.items()):
        shift = (gi - (n - 1) / 2) * width * 0.04 if n > 1 else 0.0
        err = [e if isinstance(e, int | float) and math.isfinite(e) else 0.0 for _, _, e in pts]
        has_std |= any(e > 0 for e in err)
        ax.errorbar(
            [x + shift for x, _, _ in pts],
            [y for _, y, _ in pts],
            yerr=err,
            marker=MARKERS[gi % len(MARKERS)],
            capsize=3,
            label=_line_label(key, others, short, same[key]),
            color=PALETTE[gi % len(PALETTE)],
            alpha=0.9,
        )
    ax.set_xticks(xs, [axis_text(v) for v in values])
    ax.set_xlabel(_axis_label(axis))
    ax.set_ylabel(_readable(metric))
    ax.grid(alpha=0.3)
    if len(lines) > 1:
        ax.legend(fontsize=7, loc="best")
    bars = (
        "error bars: std over seeds, mean over environments"
        if has_std
        else "no error bars: no std over seeds"
    )
    ax.set_title(f"{_readable(metric)} vs {AXIS_LABELS.get(axis, axis)}\n({bars})", fontsize=10)
    fig.tight_layout()
    path = (
        out
        / f"{re.sub(r'[^A-Za-z0-9._-]+', '_', metric)}__vs__{re.sub(r'[^A-Za-z0-9._-]+', '_', axis)}.png"
    )
    png = io.BytesIO()
    fig.savefig(png, format="png")
    plt.close(fig)
    atomic_write_bytes(path, png.getvalue())
    return path
