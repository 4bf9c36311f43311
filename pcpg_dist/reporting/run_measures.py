"""What a run measured, read back from its summary tables for the paper comparison.

Each function reads the per-environment CSVs a run wrote (only files inside the summary folder,
:func:`~pcpg_dist.reporting.report_data.inside`) and says in one line what the paper's table or
figure would show: lengths by p, the cross-accuracy diagonal, where a row's maximum lies.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pcpg_dist.common.errors import DataError
from pcpg_dist.reporting.report_data import inside, read_csv


def env_tables(summary: Path, envs: list[str], name: str) -> list[pd.DataFrame]:
    out = []
    for env in envs:
        path = summary / env / f"{name}.csv"
        if inside(path, summary):
            df = read_csv(path)
            if df is not None and len(df):
                out.append(df)
    return out


def length_summary(tables: list[pd.DataFrame]) -> str:
    """PCPG's mean length from the lowest to the highest p and its styles' spread at the highest p,
    from length tables (method, k, p, mean): the rollouts' (rollout_length) or the kept data's
    (subset_length)."""
    every = pd.concat(tables) if tables else None
    d = None if every is None else every[every.method == "pcpg"]
    if d is None or not len(d):
        return "—"

    def mean_by_p(rows: pd.DataFrame) -> pd.Series:
        if "n" not in rows:  # rollouts: one figure per agent, each from as many rollouts
            return rows.groupby("p")["mean"].mean()
        # kept data: over the kept trajectories, so that at p = 1, where the clusters together keep
        # what No Clustering keeps, the two figures are equal
        w = rows["n"].to_numpy(float) * rows["mean"].to_numpy(float)
        return pd.Series(w, index=rows.index).groupby(rows.p).sum() / rows.groupby("p")["n"].sum()

    pc = mean_by_p(d)
    at_top = d[d.p == d.p.max()]["mean"]
    text = (
        f"PCPG mean length {pc.iloc[0]:.1f} at p={pc.index[0]:g} to {pc.iloc[-1]:.1f} at "
        f"p={pc.index[-1]:g}; styles at p={d.p.max():g} from {at_top.min():.1f} to {at_top.max():.1f}"
    )
    nc = every[every.method == "nc"]
    if len(nc):
        nc_p = mean_by_p(nc)
        text += f"; No Clustering {nc_p.iloc[0]:.1f} to {nc_p.iloc[-1]:.1f}"
    return text


def kept_lengths(summary: Path, envs: list[str]) -> str:
    """Figs. 5 and 6 answered from the data: the length of the trajectories each agent imitates
    (subset_length), whether or not the domain plays rollouts."""
    return length_summary(env_tables(summary, envs, "subset_length"))


def _by_style(summary: Path, env: str, matrix: pd.DataFrame) -> pd.DataFrame | None:
    """``matrix`` (rows and columns k<c>) reordered into style order (R1, R2, ...), where the
    environment's clusters stand for its styles one to one (``cluster_style.csv``); else None."""
    table = env_tables(summary, [env], "cluster_style")  # checked: k and style are numbers
    if not table:
        return None
    for col in ("k", "style"):
        values = table[0][col].to_numpy(float)
        if not (np.isfinite(values) & (values == np.round(values))).all():
            raise DataError(
                f"{summary / env / 'cluster_style.csv'}: column {col!r} must hold whole numbers"
            )
    style = {f"k{int(k)}": int(s) for k, s in zip(table[0]["k"], table[0]["style"], strict=True)}
    names = list(matrix.index)
    order = sorted(names, key=lambda n: style.get(n, -1))
    if sorted(style.get(n, -1) for n in names) != list(range(len(names))):
        return None  # a style with two clusters, or one with none: no one-to-one order
    out = matrix.loc[order, order]
    out.index = out.columns = [f"R{style[n] + 1}" for n in order]
    return out


def matrices(summary: Path, envs: list[str], name: str) -> dict[str, pd.DataFrame]:
    """Each environment's k x k table ``name`` (cross_accuracy, correlation), rows by cluster."""
    return {
        env: t[0].set_index(t[0].columns[0]).astype(float)
        for env in envs
        if (t := env_tables(summary, [env], name))
    }


def row_max(mats: dict[str, pd.DataFrame]) -> str:
    """In how many rows, over the environments, the diagonal cell is the row's maximum (a NaN
    cell, e.g. the correlation of a constant column, is the maximum of nothing)."""

    def top(m: np.ndarray) -> int:
        return sum(bool(np.isfinite(m[i, i]) and m[i, i] >= np.nanmax(m[i])) for i in range(len(m)))

    rows = sum(top(m.to_numpy()) for m in mats.values())
    return f"the row maximum in {rows} of {sum(len(m) for m in mats.values())} rows"


def cross_summary(summary: Path, envs: list[str]) -> str:
    """Table 4 in one line: the cross-accuracy diagonal and off-diagonal range, in style order
    (R1, R2, ...) and averaged over environments where every environment's clusters match its
    styles one to one; otherwise each environment's matrix is in its own cluster order, so only
    per-environment figures are averaged."""
    mats = matrices(summary, envs, "cross_accuracy")
    if not mats:
        return "—"
    aligned = [_by_style(summary, env, m) for env, m in mats.items()]
    if all(a is not None for a in aligned) and len({tuple(a.index) for a in aligned}) == 1:
        m = sum(a.to_numpy() for a in aligned) / len(aligned)
        note = f" (styles R1 to R{len(m)}: clusters matched to styles)"
    elif len(mats) == 1:
        m, note = (
            next(iter(mats.values())).to_numpy(),
            " (by cluster: not matched to styles one to one)",
        )
    else:
        diag = [float(np.mean(np.diagonal(m.to_numpy()))) for m in mats.values()]
        return (
            f"diagonal mean {np.mean(diag):.2f}, {row_max(mats)} (clusters not matched to styles "
            f"one to one, so not averaged cell by cell)"
        )
    off = [m[i, j] for i in range(m.shape[0]) for j in range(m.shape[1]) if i != j]
    text = "diagonal " + " / ".join(f"{m[i, i]:.2f}" for i in range(min(m.shape)))
    return text + (f"; off-diagonal {min(off):.2f} to {max(off):.2f}" if off else "") + note
