"""One environment's evaluation on disk: every table as CSV and JSON, ``metrics.json``, and the
figures.

Why apart: the tables are computed the same whether or not they are written (a tuning trial
keeps them in memory), so the files are one last step over the finished tables.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from pcpg_dist.config.stages import EvalConfig
from pcpg_dist.dataset import Dataset
from pcpg_dist.domains.base import DomainHooks

#: tables whose index (the cluster names) is part of the CSV
INDEXED_TABLES = ("cross_accuracy", "cross_accuracy_std", "correlation", "correlation_std")


def write_evaluation(
    out_dir: str | Path,
    tables: dict[str, pd.DataFrame],
    metrics: dict[str, float],
    rollout_sets: dict[tuple, Dataset],
    hooks: DomainHooks,
    cfg: EvalConfig,
) -> dict[str, Path]:
    """Write the tables, metrics and (``eval.figures``) figures to ``out_dir``; the figures'
    paths by name."""
    figures: dict[str, Path] = {}
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for name, df in tables.items():
        df.to_csv(out / f"{name}.csv", index=name in INDEXED_TABLES)
        df.reset_index().to_json(out / f"{name}.json", orient="records", indent=1)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=1, sort_keys=True))
    if cfg.figures:
        from pcpg_dist.stages import figures as fig

        figures = fig.write_all(tables, out, rollout_sets, hooks.draw, cfg.greedy)
    return figures
