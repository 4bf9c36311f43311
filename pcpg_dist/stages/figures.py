"""PNG figures of the evaluation tables (matplotlib, Agg backend: no display needed).

Kept apart from evaluation.py so the numbers can be computed (and tested) without plotting, and
the plots re-drawn from saved tables.

One look for every figure the project draws (per environment, and across environments in
:func:`accuracy_figure`):

- p on the x axis always increases left to right (0.1 ... 1), ticks at the p values run;
- colours from the Okabe-Ito palette (distinguishable with every common colour-vision
  deficiency), and each method keeps its colour, marker and line style in every figure;
- heatmaps use perceptually uniform, colour-blind-safe maps (cividis; RdBu for signed values)
  with the cell text black or white by the cell's luminance, so every number stays readable.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from contextlib import contextmanager
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from cycler import cycler  # noqa: E402

from pcpg_dist.dataset import Dataset  # noqa: E402

#: Okabe & Ito (2008), "Color Universal Design": blue, orange, green, vermillion, purple, sky, yellow
OKABE_ITO = ("#0072B2", "#E69F00", "#009E73", "#D55E00", "#CC79A7", "#56B4E9", "#F0E442", "#000000")

#: every method's look, the same in every figure
METHODS = {
    "pcpg": {"color": OKABE_ITO[0], "marker": "o", "ls": "-", "label": "PCPG"},
    "no_clustering": {"color": OKABE_ITO[1], "marker": "s", "ls": "--", "label": "No Clustering"},
    "majority": {"color": "#555555", "marker": "", "ls": "-.", "label": "majority class"},
    "random": {"color": "#000000", "marker": "", "ls": ":", "label": "random"},
}

STYLE = {
    "axes.prop_cycle": cycler(color=OKABE_ITO[:6]),
    "font.size": 9,
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "legend.fontsize": 8,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "legend.frameon": False,
    "lines.linewidth": 1.6,
    "lines.markersize": 5,
    "errorbar.capsize": 3,
    "savefig.dpi": 120,
    "image.cmap": "cividis",
}

P_LABEL = "p (top fraction of each subset kept)"


@contextmanager
def style():
    """The project's matplotlib style, for pyplot and ``matplotlib.figure.Figure`` alike."""
    with matplotlib.rc_context(STYLE):
        yield


def p_axis(ax, ps: Iterable[float]) -> None:
    """The one convention for p: increasing left to right, a tick at every p that was run."""
    ps = sorted({float(p) for p in ps})
    if not ps:
        return
    pad = 0.05 * max(ps[-1] - ps[0], 0.2)
    ax.set_xlim(ps[0] - pad, ps[-1] + pad)
    ax.set_xticks(ps, [f"{p:g}" for p in ps])
    ax.set_xlabel(P_LABEL)


def method_line(ax, method: str, x, y, yerr=None) -> None:
    """One method's curve, in its fixed colour, marker and line style."""
    look = METHODS.get(method, {"label": method})
    if yerr is not None and np.isfinite(np.asarray(yerr, float)).any():
        ax.errorbar(x, y, yerr=np.nan_to_num(np.asarray(yerr, float)), **look)
    else:
        ax.plot(x, y, **look)


def accuracy_axes(ax, acc: pd.DataFrame) -> None:
    """Fig. 4 on one axis from the long table (method, p, mean, std)."""
    for method in METHODS:
        d = acc[acc.method == method].sort_values("p")
        if len(d):
            err = d["std"] if method in ("pcpg", "no_clustering") else None
            method_line(ax, method, d.p, d["mean"], err)
    p_axis(ax, acc.p)
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("test accuracy")


def method_legend(ax) -> tuple[list, list[str]]:
    """An axis's legend entries in the methods' fixed order (PCPG first), others after."""
    handles, labels = ax.get_legend_handles_labels()
    order = [m["label"] for m in METHODS.values()]
    ranked = sorted(
        zip(handles, labels, strict=True),
        key=lambda hl: order.index(hl[1]) if hl[1] in order else len(order),
    )
    return [h for h, _ in ranked], [lab for _, lab in ranked]


def long_accuracy(acc: pd.DataFrame) -> pd.DataFrame:
    """The wide summary table as (env, method, p, mean, std) rows, as one environment's table is."""
    parts = []
    for method, mean, std in (
        ("pcpg", "pcpg", "pcpg_std"),
        ("no_clustering", "no_clustering", "no_clustering_std"),
        ("majority", "majority", None),
        ("random", "random", None),
    ):
        part = acc[["env", "p"]].assign(method=method, mean=acc[mean], std=acc[std] if std else 0.0)
        parts.append(part)
    return pd.concat(parts, ignore_index=True)


def accuracy_figure(acc: pd.DataFrame, path: Path) -> None:
    """Fig. 4 across environments: the mean over environments (the numbers the report's headline
    quotes) as one panel large enough to read at half a laptop's width, each environment a thin
    line of its method's colour behind it (each environment's own Fig. 4 is in its section)."""
    from matplotlib.figure import Figure

    long = long_accuracy(acc)
    envs = list(dict.fromkeys(acc["env"]))
    mean = long.groupby(["method", "p"], as_index=False, sort=False)[["mean", "std"]].mean()
    bigger = {
        "font.size": 11,
        "axes.titlesize": 12,
        "axes.labelsize": 11,
        "legend.fontsize": 10,
        "xtick.labelsize": 10,
        "ytick.labelsize": 10,
        "lines.linewidth": 2.0,
        "lines.markersize": 6,
    }
    with style(), matplotlib.rc_context(bigger):
        fig = Figure(figsize=(5.6, 4.2))
        ax = fig.subplots()
        if len(envs) > 1:
            for env in envs:
                for method in ("pcpg", "no_clustering"):
                    d = long[(long["env"] == env) & (long["method"] == method)].sort_values("p")
                    ax.plot(
                        d.p,
                        d["mean"],
                        color=METHODS[method]["color"],
                        lw=0.8,
                        alpha=0.35,
                        ls=METHODS[method]["ls"],
                    )
        accuracy_axes(ax, mean)
        ax.set_title(
            f"Mean over {len(envs)} environment{'s' if len(envs) != 1 else ''}"
            + (" (thin lines: each one)" if len(envs) > 1 else "")
        )
        handles, labels = method_legend(ax)
        fig.legend(handles, labels, loc="lower center", ncol=2, bbox_to_anchor=(0.5, 0))
        fig.tight_layout(rect=(0, 0.14, 1, 1))
        fig.savefig(path)


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def accuracy_vs_p(acc: pd.DataFrame, path: Path) -> Path:
    """Fig. 4: accuracy vs p for PCPG, No Clustering, the majority class and random, with one std."""
    with style():
        fig, ax = plt.subplots(figsize=(4.8, 3.4))
        accuracy_axes(ax, acc)
        ax.legend(*method_legend(ax), loc="lower right")
        return _save(fig, path)


def _text_colour(rgba) -> str:
    r, g, b = rgba[:3]
    return "black" if 0.2126 * r + 0.7152 * g + 0.0722 * b > 0.45 else "white"


def heatmap(
    matrix: pd.DataFrame,
    path: Path,
    title: str,
    vmin: float | None = None,
    vmax: float | None = None,
    cmap: str = "cividis",
) -> Path:
    """Table 4 / Fig. 7: models (rows) against subsets (columns), values written in."""
    values = matrix.to_numpy(dtype=float)
    k = max(values.shape)
    size = min(1.9 + 0.55 * k, 8.0)
    with style():
        fig, ax = plt.subplots(figsize=(size + 0.8, size))
        im = ax.imshow(values, vmin=vmin, vmax=vmax, cmap=cmap)
        ax.grid(False)
        ax.set_xticks(range(values.shape[1]), [f"H {c}" for c in matrix.columns])
        ax.set_yticks(range(values.shape[0]), [f"π {i}" for i in matrix.index])
        ax.set_xlabel("test subset H_k'")
        ax.set_ylabel("model π_k")
        font = 9 if k <= 5 else 8 if k <= 8 else 6
        for (i, j), v in np.ndenumerate(values):
            colour = _text_colour(im.cmap(im.norm(v)))
            ax.text(j, i, f"{v:.2f}", ha="center", va="center", fontsize=font, color=colour)
        ax.set_title(title)
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
        return _save(fig, path)


def style_weights(table: pd.DataFrame, path: Path) -> Path:
    """What each cluster weighs (``choice_mix``): move features (rows) against clusters
    (columns), each weight per standard deviation of its feature, written in."""
    weights = table.drop(columns="feature")
    values = weights.to_numpy(dtype=float)
    n_features, k = values.shape
    top = max(float(np.abs(values).max(initial=0.0)), 1e-9)
    longest = max((len(str(n)) for n in table["feature"]), default=8)
    with style():
        fig, ax = plt.subplots(figsize=(2.0 + 0.08 * longest + 0.8 * k, 1.2 + 0.3 * n_features))
        im = ax.imshow(values, vmin=-top, vmax=top, cmap="RdBu_r", aspect="auto")
        ax.grid(False)
        ax.set_xticks(range(k), [str(c) for c in weights.columns])
        ax.set_yticks(range(n_features), [str(n) for n in table["feature"]])
        ax.set_xlabel("cluster")
        for (i, j), v in np.ndenumerate(values):
            colour = _text_colour(im.cmap(im.norm(v)))
            ax.text(j, i, f"{v:+.1f}", ha="center", va="center", fontsize=8, color=colour)
        ax.set_title("what each cluster weighs\n(per std. dev. of each move feature)", fontsize=10)
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
        return _save(fig, path)


def rollout_length(length: pd.DataFrame, path: Path, mode: str, ylabel: str | None = None) -> Path:
    """Fig. 5/6: mean rollout (or kept-trajectory) length vs p per style and for No Clustering."""
    with style():
        fig, ax = plt.subplots(figsize=(4.8, 3.4))
        clusters = sorted(int(k) for k in length.loc[length.method != "nc", "k"].unique())
        markers = "o^vD<>px"
        for i, c in enumerate(clusters):
            d = length[(length.method != "nc") & (length.k == c)].sort_values("p")
            ax.errorbar(
                d.p,
                d["mean"],
                yerr=d["std"].fillna(0),
                color=OKABE_ITO[(i + 2) % 6],
                marker=markers[i % len(markers)],
                ls="-",
                label=f"π k{c}",
            )
        d = length[length.method == "nc"].sort_values("p")
        if len(d):
            method_line(ax, "no_clustering", d.p, d["mean"], d["std"].fillna(0))
        p_axis(ax, length.p)
        ax.set_ylabel(ylabel or f"mean rollout length ({mode} actions)")
        ax.legend(ncol=2)
        return _save(fig, path)


def corruption(acc: pd.DataFrame, path: Path) -> Path:
    """Fig. 9: accuracy vs label corruption c, with the No Clustering reference."""
    with style():
        fig, ax = plt.subplots(figsize=(4.8, 3.4))
        d = acc.sort_values("c")
        ax.errorbar(
            d.c,
            d["mean"],
            yerr=d["std"],
            color=METHODS["pcpg"]["color"],
            marker="o",
            label="PCPG (corrupted labels)",
        )
        if "baseline_mean" in d and d["baseline_mean"].notna().all():
            ax.axhline(
                float(d["baseline_mean"].iloc[0]),
                ls="--",
                color=METHODS["no_clustering"]["color"],
                label="No Clustering",
            )
        ax.set_xticks(sorted(d.c.unique()))
        ax.set_xlabel("fraction of corrupted labels c")
        ax.set_ylabel("test accuracy")
        ax.legend()
        return _save(fig, path)


def drawn_rollouts(
    rollouts: dict[tuple[int, int], Dataset], draw: Callable[..., None], path: Path, mode: str
) -> Path:
    """Fig. 8: one rollout of each style's policy, drawn by the domain."""
    items = sorted(rollouts.items())
    with style():
        fig, axes = plt.subplots(1, len(items), figsize=(2.6 * len(items), 2.9), squeeze=False)
        for ax, ((k, style_id), ds) in zip(axes[0], items, strict=True):
            ax.grid(False)
            draw(ax, ds)
            ax.set_title(f"π k{k} (style {style_id}, {mode})", fontsize=9)
        return _save(fig, path)


def write_all(
    tables: dict[str, pd.DataFrame],
    out: Path,
    rollouts: dict[tuple[int, int], Dataset],
    draw: Callable[..., None] | None,
    greedy: bool,
) -> dict[str, Path]:
    """Every figure whose table exists; returns name -> PNG path."""
    mode = "greedy" if greedy else "sampled"
    figs = {}
    if "accuracy" in tables:
        figs["accuracy_vs_p"] = accuracy_vs_p(tables["accuracy"], out / "accuracy_vs_p.png")
    if "cross_accuracy" in tables:
        figs["cross_accuracy"] = heatmap(
            tables["cross_accuracy"],
            out / "cross_accuracy.png",
            "accuracy of π_k on H_k' (mean over p)",
            0,
            1,
        )
    if "correlation" in tables:
        figs["correlation"] = heatmap(
            tables["correlation"],
            out / "correlation.png",
            "corr(per-trajectory accuracy, in H_k')",
            -1,
            1,
            "RdBu_r",
        )
    if "style_weights" in tables:
        figs["style_weights"] = style_weights(tables["style_weights"], out / "style_weights.png")
    if "rollout_length" in tables:
        figs["rollout_length"] = rollout_length(
            tables["rollout_length"], out / "rollout_length.png", mode
        )
    if "subset_length" in tables:
        figs["subset_length"] = rollout_length(
            tables["subset_length"],
            out / "subset_length.png",
            mode,
            "kept trajectory length (steps)",
        )
    if "corruption_accuracy" in tables:
        figs["corruption"] = corruption(tables["corruption_accuracy"], out / "corruption.png")
    if rollouts and draw is not None:
        figs["rollouts"] = drawn_rollouts(rollouts, draw, out / "rollouts.png", mode)
    return figs


#: per-environment tables written with their row index (the model names of a matrix)
INDEXED = ("cross_accuracy", "correlation")


def redraw(summary: Path, greedy: bool = True) -> list[Path]:
    """Re-draw a summary folder's figures from its saved tables, in the current style.

    Everything but Fig. 8 (it draws the rollouts themselves, which are not kept): use it after a
    style change, or on a summary downloaded from MLflow. Returns the PNGs written.
    """
    summary = Path(summary)
    written = []
    if (summary / "accuracy_vs_p.csv").is_file():
        accuracy_figure(pd.read_csv(summary / "accuracy_vs_p.csv"), summary / "accuracy_vs_p.png")
        written.append(summary / "accuracy_vs_p.png")
    for env in sorted(d for d in summary.iterdir() if d.is_dir() and not d.is_symlink()):
        tables = {}
        for csv in env.glob("*.csv"):
            try:
                tables[csv.stem] = pd.read_csv(csv, index_col=0 if csv.stem in INDEXED else None)
            except pd.errors.EmptyDataError:
                continue
        written += write_all(tables, env, {}, None, greedy).values()
    return written
