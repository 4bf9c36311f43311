"""What an evaluation returns, and the one rule for a metric over seeds (mean and std).

Why a module of its own: every part of the evaluation (accuracy, cross accuracy, rollouts,
corruption) and the summary across environments report through these.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd


@dataclass(frozen=True)
class EvalResult:
    tables: dict[str, pd.DataFrame]
    metrics: dict[str, float]
    figures: dict[str, Path] = field(default_factory=dict)


def mean_std(values: list[float]) -> tuple[float, float]:
    """NaN-ignoring mean and the std with ddof 0 (0.0 for a single value)."""
    a = np.asarray(values, float)
    return float(np.nanmean(a)), float(np.nanstd(a)) if len(a) > 1 else 0.0
