"""PNG figures of the evaluation tables (matplotlib, Agg backend: no display needed).

Kept apart from evaluation.py so the numbers can be computed (and tested) without plotting, and
the plots re-drawn from saved tables.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from pcpg_dist.dataset import Dataset  # noqa: E402


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def accuracy_vs_p(acc: pd.DataFrame, path: Path) -> Path:
    """Fig. 4: accuracy vs p for PCPG, No Clustering, the majority class and random, with one std."""
    fig, ax = plt.subplots(figsize=(4.5, 3.2))
    for method, style in (("pcpg", "o-"), ("no_clustering", "s--"), ("majority", "-."), ("random", ":")):
        d = acc[acc.method == method].sort_values("p")
        if len(d):
            ax.errorbar(d.p, d["mean"], yerr=d["std"], fmt=style, capsize=3, label=method)
    ax.set_xlabel("p (top fraction kept)")
    ax.set_ylabel("test accuracy")
    ax.invert_xaxis()
    ax.legend(fontsize=8)
    return _save(fig, path)


def heatmap(matrix: pd.DataFrame, path: Path, title: str, vmin: float | None = None,
            vmax: float | None = None, cmap: str = "viridis") -> Path:
    """Table 4 / Fig. 7: models (rows) against subsets (columns), values written in."""
    fig, ax = plt.subplots(figsize=(3.8, 3.3))
    im = ax.imshow(matrix.to_numpy(), vmin=vmin, vmax=vmax, cmap=cmap)
    ax.set_xticks(range(matrix.shape[1]), matrix.columns)
    ax.set_yticks(range(matrix.shape[0]), [f"pi_{i}" for i in matrix.index])
    ax.set_xlabel("test subset H_k'")
    for (i, j), v in np.ndenumerate(matrix.to_numpy()):
        ax.text(j, i, f"{v:.2f}", ha="center", va="center", fontsize=7, color="w")
    ax.set_title(title, fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.046)
    return _save(fig, path)


def rollout_length(length: pd.DataFrame, path: Path, mode: str,
                   ylabel: str | None = None) -> Path:
    """Fig. 5/6: mean rollout (or kept-trajectory) length vs p per style and for No Clustering."""
    fig, ax = plt.subplots(figsize=(4.5, 3.2))
    for (method, k), d in length.groupby(["method", "k"]):
        d = d.sort_values("p")
        label = "no clustering" if method == "nc" else f"pi_k{k}"
        ax.errorbar(d.p, d["mean"], yerr=d["std"].fillna(0), fmt="s--" if method == "nc" else "o-",
                    capsize=3, label=label)
    ax.set_xlabel("p")
    ax.set_ylabel(ylabel or f"mean rollout length ({mode} actions)")
    ax.invert_xaxis()
    ax.legend(fontsize=7)
    return _save(fig, path)


def corruption(acc: pd.DataFrame, path: Path) -> Path:
    """Fig. 9: accuracy vs label corruption c, with the No Clustering reference."""
    fig, ax = plt.subplots(figsize=(4.5, 3.2))
    ax.errorbar(acc.c, acc["mean"], yerr=acc["std"], fmt="o-", capsize=3, label="PCPG (corrupted)")
    if "baseline_mean" in acc and acc["baseline_mean"].notna().all():
        ax.axhline(float(acc["baseline_mean"].iloc[0]), ls="--", color="grey", label="no clustering")
    ax.set_xlabel("fraction of corrupted labels c")
    ax.set_ylabel("test accuracy")
    ax.legend(fontsize=8)
    return _save(fig, path)


def drawn_rollouts(rollouts: dict[tuple[int, int], Dataset], draw: Callable[..., None],
                   path: Path, mode: str) -> Path:
    """Fig. 8: one rollout of each style's policy, drawn by the domain."""
    items = sorted(rollouts.items())
    fig, axes = plt.subplots(1, len(items), figsize=(2.6 * len(items), 2.8), squeeze=False)
    for ax, ((k, style), ds) in zip(axes[0], items, strict=True):
        draw(ax, ds)
        ax.set_title(f"pi_k{k} (style {style}, {mode})", fontsize=8)
    return _save(fig, path)


def write_all(tables: dict[str, pd.DataFrame], out: Path,
              rollouts: dict[tuple[int, int], Dataset], draw: Callable[..., None] | None,
              greedy: bool) -> dict[str, Path]:
    """Every figure whose table exists; returns name -> PNG path."""
    mode = "greedy" if greedy else "sampled"
    figs = {}
    if "accuracy" in tables:
        figs["accuracy_vs_p"] = accuracy_vs_p(tables["accuracy"], out / "accuracy_vs_p.png")
    if "cross_accuracy" in tables:
        figs["cross_accuracy"] = heatmap(tables["cross_accuracy"], out / "cross_accuracy.png",
                                         "accuracy of pi_k on H_k' (mean over p)", 0, 1)
    if "correlation" in tables:
        figs["correlation"] = heatmap(tables["correlation"], out / "correlation.png",
                                      "corr(per-trajectory accuracy, in H_k')", -1, 1, "coolwarm")
    if "rollout_length" in tables:
        figs["rollout_length"] = rollout_length(tables["rollout_length"], out / "rollout_length.png", mode)
    if "subset_length" in tables:
        figs["subset_length"] = rollout_length(tables["subset_length"], out / "subset_length.png",
                                               mode, "kept trajectory length (steps)")
    if "corruption_accuracy" in tables:
        figs["corruption"] = corruption(tables["corruption_accuracy"], out / "corruption.png")
    if rollouts and draw is not None:
        figs["rollouts"] = drawn_rollouts(rollouts, draw, out / "rollouts.png", mode)
    return figs
