"""Across environments: every metric's mean over environments, and every table stacked with an
``env`` column.

Why apart from one environment's evaluation: the summary reads finished results only (from this
run or from a cache), never the data or the agents.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from pcpg_dist.stages.evaluation.results import EvalResult


def summarize(results: dict[str, EvalResult], out_dir: str | Path | None = None) -> EvalResult:
    """Across environments: every metric's mean over environments, tables stacked with ``env``."""
    names = sorted({m for r in results.values() for m in r.metrics})
    metrics = {}
    for name in names:
        vals = [r.metrics[name] for r in results.values() if name in r.metrics]
        metrics[name] = float(np.nanmean(vals))
    for env, r in results.items():
        for name, value in r.metrics.items():
            metrics[f"{env}/{name}"] = value
    tables = {}
    for name in sorted({t for r in results.values() for t in r.tables}):
        parts = [
            r.tables[name].reset_index().assign(env=env)
            for env, r in results.items()
            if name in r.tables
        ]
        tables[name] = pd.concat(parts, ignore_index=True)
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        for name, df in tables.items():
            df.to_csv(out / f"{name}.csv", index=False)
            df.to_json(out / f"{name}.json", orient="records", indent=1)
        (out / "metrics.json").write_text(json.dumps(metrics, indent=1, sort_keys=True))
    return EvalResult(tables, metrics, {})
