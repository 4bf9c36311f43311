"""`pcpg sweep`: a grid over config axes, every point run together on Ray, shared units run once.

The points of a sweep are configs that differ in a few dotted keys. They run as one batch through
:func:`pcpg_dist.orchestration.runner.run_points`: their tasks interleave on the cluster, and the content-keyed
cache (``<workdir>/<name>/cache``, the same one `pcpg run` of the base config uses) shares every
unit whose inputs are equal: points that differ only in ``bc.*`` train on one dataset and one
clustering; points that differ only in evaluation settings reuse the trained agents.

Outputs under ``<workdir>/<name>/sweep/``: ``points/<point>/`` (each point's summary, report and
agents, as `pcpg run` writes them), ``summary.csv`` (one row per point: its axes, the headline
metrics and their std over seeds), one PNG per headline metric against each axis, ``sweep.json``
(the axes, the fixed overrides, the figures) and ``report.html``. MLflow: one parent run per
sweep, one child per point (its overrides as params, its headline metrics), the environments under
each point as in `pcpg run`.

A point's folder is named by its axis values and a hash of everything that makes its config
differ from the file (axes, fixed overrides, the validated config's hash), so two sweeps of one
config never share a point folder and every sweep finds its own finished points again. ``points/``
keeps the points of every sweep run there; the files beside it describe the last sweep only (a
figure the last sweep did not draw is removed).

Rerunning the same command is idempotent: finished points are read back, not rerun or relogged;
adding a value to an axis runs only the new points.
"""

from __future__ import annotations

import json
import math
import re
import reprlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pcpg_dist.common.errors import ConfigError
from pcpg_dist.common.point_labels import axis_text
from pcpg_dist.config.overrides import apply_overrides, parse_overrides, read_raw, sweep_points


def _p_keys(rows: list[dict[str, Any]]) -> list[str]:
    """The p values of the rows' ``pcpg/accuracy/p<x>`` keys, largest first (as written in the keys)."""
    found = {
        k.rsplit("/p", 1)[1]
        for r in rows
        for k in r
        if re.fullmatch(r"pcpg/accuracy/p[0-9.e-]+", k)
    }
    return sorted(found, key=float, reverse=True)


def best_points(
    axes: dict[str, list], rows: list[dict[str, Any]]
) -> tuple[dict[str, float], dict[str, str]]:
    """The sweep run's headline: ``best/<metric>`` for clustering accuracy, PCPG accuracy at the
    largest p and PCPG's lead at the smallest p, and for each the point that has it (its MLflow
    run name; ``(+n tied)`` when other points have the same value)."""
    from pcpg_dist.common.point_labels import point_label

    ps = _p_keys(rows)
    keys = [
        "clustering/accuracy",
        *([f"pcpg/accuracy/p{ps[0]}", f"pcpg_lead/p{ps[-1]}"] if ps else []),
    ]
    best, where = {}, {}
    for key in keys:
        have = [r for r in rows if isinstance(r.get(key), int | float) and math.isfinite(r[key])]
        if not have:
            continue
        top = max(r[key] for r in have)
        tied = [r for r in have if r[key] == top]
        best[f"best/{key}"] = float(top)
        where[key] = point_label({a: axis_text(tied[0][a]) for a in axes}) + (
            f" (+{len(tied) - 1} tied)" if len(tied) > 1 else ""
        )
    return best, where


def point_slug(
    axes: dict[str, Any], fixed: dict[str, Any] | None = None, config_hash: str = ""
) -> str:
    """A stable folder name for a point: its axis values, readable and made safe, plus a short hash
    of everything that sets its config apart (axes, fixed overrides, the config's own hash)."""
    from pcpg_dist.common.run_folders import slug

    text = "_".join(
        f"{k}={json.dumps(v) if isinstance(v, list | dict) else v}" for k, v in axes.items()
    )
    return slug(text, [axes, fixed or {}, config_hash], fallback="point")


@dataclass
class SweepPlan:
    """A sweep before it runs: its base config, axes, fixed overrides and points (folders included)."""

    base: Any  # ExperimentConfig of the file with the fixed overrides
    axes: dict[str, list]
    fixed: dict[str, Any]
    combos: list[dict[str, Any]]
    points: list  # runner.Point, one per combo
    root: Path  # <workdir>/<name>
    description: str

    @property
    def out(self) -> Path:
        return self.root / "sweep"


def plan_sweep(
    config: str | Path | dict,
    axes_args: list[str],
    overrides: list[str] | None = None,
    workdir: Path = Path("runs"),
    command: str = "",
) -> SweepPlan:
    """Validate the sweep (every point's config) and name its points' folders; nothing runs.

    ``config``: a YAML file, or a config mapping (from Python; its ``sweep`` key, if any, is
    the file's ``sweep:`` section, and relative paths in it are read from the current folder)."""
    from pcpg_dist.config.experiment import parse_config
    from pcpg_dist.orchestration.points import Point

    if isinstance(config, dict):
        raw = dict(config)
        section, source, base_dir = raw.pop("sweep", None), "<python>", Path.cwd()
    else:
        raw, section = read_raw(config)
        source, base_dir = str(config), Path(config).parent
    fixed = parse_overrides(overrides or [])
    raw = apply_overrides(raw, fixed)
    base = parse_config(raw, source=source, base_dir=base_dir)
    axes, combos = sweep_points(section, axes_args, base.domain)
    if both := sorted(set(fixed) & set(axes)):  # the axis would silently win
        raise ConfigError(
            f"{both[0]!r} is both a sweep axis and a single value ({both[0]}={reprlib.repr(fixed[both[0]])}); "
            f"give it once"
        )
    root = Path(workdir).resolve() / base.name
    points = []
    for combo in combos:
        cfg = parse_config(
            apply_overrides(raw, combo),
            source=f"{source} with {describe(combo)}",
            base_dir=base_dir,
        )
        points.append(
            Point(
                cfg,
                root / "sweep" / "points" / point_slug(combo, fixed, cfg.hash()),
                params={k: axis_text(v) for k, v in combo.items()},
                command=f"{command} [point {describe(combo)}]" if command else "",
            )
        )
    description = (
        f"Sweep of {base.name} ({Path(source).name}) over {', '.join(axes)}: {len(points)} points "
        f"({' x '.join(str(len(v)) for v in axes.values())})"
        + (f"; fixed: {describe(fixed)}" if fixed else "")
    )
    return SweepPlan(base, axes, fixed, combos, points, root, description)


def describe(combo: dict[str, Any]) -> str:
    return ", ".join(f"{k}={axis_text(v)}" for k, v in combo.items())
