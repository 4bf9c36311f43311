"""The paper beside the run: its protocol (what a run must use to be a reproduction), the
headline numbers, and for every table and figure the paper has what it reports and what this run
measured. Numbers come from the domain's ``paper_numbers``; where the paper states a finding rather
than a number (../shared/PAPER.md), the finding.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pcpg_dist.common.errors import DataError
from pcpg_dist.config.domains import MarioLoadConfig
from pcpg_dist.config.stages import BCConfig, RankConfig
from pcpg_dist.reporting.report_data import PaperRow, fmt, inside, read_csv

#: domains the paper has results for (others get no paper column and a banner saying so)
PAPER_DOMAINS = ("gridworld", "minidungeons", "mario")

#: the paper's protocol, checked against a run's config: (key, paper value, domains or None = all)
PROTOCOL: tuple[tuple[str, object, tuple[str, ...] | None], ...] = (
    ("seeds", 4, None),  # compared by count: the paper reports 4 seeds
    ("ranking.ps", [1.0, 0.75, 0.5, 0.25, 0.1], None),
    ("ranking.beta", 0.1, None),
    ("ranking.style_margin", 0.0, None),
    ("clustering.method", "lstm_dec", None),
    ("bc.hidden_layers", 3, None),
    ("bc.hidden_size", 5, None),
    ("bc.epochs", 2000, None),
    ("bc.batch_size", None, None),  # full batch
    ("bc.init", "scratch", None),  # every agent from its own initialisation
    ("clustering.k", 4, ("gridworld",)),
    ("gridworld.environments", ["E1", "E2", "E3", "E4", "E5"], ("gridworld",)),
    ("gridworld.random_layouts", None, ("gridworld",)),
    ("pbtg.episodes", 20000, ("gridworld",)),
    ("pbtg.trajectories_per_style", 8000, ("gridworld",)),
    ("pbtg.dataset_per_style", 1000, ("gridworld",)),
    ("mario.event", "id", ("mario",)),  # the state (j, k, r, c, d, e): the event id as one number
    ("mario.counters", True, ("mario",)),
    ("mario.increments", False, ("mario",)),
)
#: how the report names a paper setting whose value alone would not say it
PAPER_MEANS = {"bc.batch_size": "none (full batch)"}

#: a protocol setting added after runs were logged: a recorded config without it ran with its default
ABSENT_MEANS = {
    "ranking.style_margin": RankConfig.model_fields["style_margin"].default,
    "bc.init": BCConfig.model_fields["init"].default,
    "mario.event": "id",  # runs before the setting (2026-11-21) read the event id as a number
    **{
        f"mario.{name}": MarioLoadConfig.model_fields[name].default
        for name in ("counters", "increments")
    },
}


# ----------------------------------------------------------------------------- content
def paper_numbers(domain: str | None) -> dict[str, str]:
    """The paper's figures for a domain (none for a domain that is not installed here)."""
    from pcpg_dist.common.errors import PcpgError
    from pcpg_dist.domains import registry

    try:
        return dict(registry.get(str(domain)).paper_numbers)
    except PcpgError:
        return {}


def _get(cfg: dict, key: str):
    value = cfg
    for part in key.split("."):
        if not isinstance(value, dict) or part not in value:
            return None
        value = value[part]
    return value


def protocol_differences(cfg: dict) -> list[tuple[str, str, str]]:
    """(setting, this run, the paper) for every protocol setting the config changes."""
    domain = cfg.get("domain", "gridworld")
    out = []
    for key, paper, domains in PROTOCOL:
        if domains is not None and domain not in domains:
            continue
        ours = _get(cfg, key)
        if ours is None:
            ours = ABSENT_MEANS.get(key)
        if key == "seeds":
            if len(ours or []) != paper:
                out.append((key, f"{len(ours or [])} seeds", f"{paper} seeds"))
            continue
        if isinstance(paper, list) and isinstance(ours, list):
            same = [float(x) if isinstance(x, int | float) else x for x in ours] == paper
        else:
            same = ours == paper
        if not same:
            out.append((key, plain(ours), PAPER_MEANS.get(key, plain(paper))))
    return out


def plain(v) -> str:
    if v is None:
        return "none"
    if isinstance(v, list | tuple):
        return ", ".join(plain(x) for x in v)
    if isinstance(v, dict):
        return "set"
    return f"{v:g}" if isinstance(v, float) else str(v)


def _ps(metrics: dict) -> list[float]:
    return sorted(
        {
            float(k.split("/p")[1])
            for k in metrics
            if k.startswith("pcpg/accuracy/p") and k.count("/") == 2
        }
    )


def headline(metrics: dict) -> dict:
    """PCPG vs No Clustering per p (mean over environments) and the clustering quality."""
    rows = []
    for p in _ps(metrics):
        pc, nc = metrics.get(f"pcpg/accuracy/p{p:g}"), metrics.get(f"baseline/accuracy/p{p:g}")
        diff = pc - nc if pc is not None and nc is not None else None
        rows.append(
            {
                "p": fmt(p, 2).rstrip("0").rstrip("."),
                "pcpg": fmt(pc),
                "nc": fmt(nc),
                "diff": "—" if diff is None else f"{diff:+.3f}",
                "ahead": diff is not None and diff > 0,
            }
        )
    wins = sum(r["ahead"] for r in rows)
    compared = sum(r["diff"] != "—" for r in rows)
    acc, ceil = metrics.get("clustering/accuracy"), metrics.get("clustering/ceiling")
    gap = metrics.get("clustering/gap_to_ceiling")
    return {
        "rows": rows,
        "wins": wins,
        "compared": compared,
        "accuracy": None if acc is None else f"{acc:.3f}",
        "ceiling": None if ceil is None else f"{ceil:.3f}",
        "gap": None if gap is None else f"{gap:+.3f}",
        "random": fmt(metrics.get("random/accuracy")),
    }


# ----------------------------------------------------------------------------- the paper's items
def _env_tables(summary: Path, envs: list[str], name: str) -> list[pd.DataFrame]:
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
    return length_summary(_env_tables(summary, envs, "subset_length"))


def _by_style(summary: Path, env: str, matrix: pd.DataFrame) -> pd.DataFrame | None:
    """``matrix`` (rows and columns k<c>) reordered into style order (R1, R2, ...), where the
    environment's clusters stand for its styles one to one (``cluster_style.csv``); else None."""
    table = _env_tables(summary, [env], "cluster_style")  # checked: k and style are numbers
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


def _matrices(summary: Path, envs: list[str], name: str) -> dict[str, pd.DataFrame]:
    """Each environment's k x k table ``name`` (cross_accuracy, correlation), rows by cluster."""
    return {
        env: t[0].set_index(t[0].columns[0]).astype(float)
        for env in envs
        if (t := _env_tables(summary, [env], name))
    }


def _row_max(mats: dict[str, pd.DataFrame]) -> str:
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
    mats = _matrices(summary, envs, "cross_accuracy")
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
            f"diagonal mean {np.mean(diag):.2f}, {_row_max(mats)} (clusters not matched to styles "
            f"one to one, so not averaged cell by cell)"
        )
    off = [m[i, j] for i in range(m.shape[0]) for j in range(m.shape[1]) if i != j]
    text = "diagonal " + " / ".join(f"{m[i, i]:.2f}" for i in range(min(m.shape)))
    return text + (f"; off-diagonal {min(off):.2f} to {max(off):.2f}" if off else "") + note


def paper_rows(domain: str, metrics: dict, summary: Path, envs: list[str]) -> list[PaperRow]:
    """Every table and figure of the paper: what the paper reports and what this run measured."""
    paper = paper_numbers(domain)
    in_paper = domain in PAPER_DOMAINS
    first = envs[0] if envs else ""

    def said(key: str, finding: str) -> str:
        if not in_paper:
            return "not in the paper (domain " + domain + ")"
        return paper.get(key, finding)

    rows = []
    h = headline(metrics)
    rows.append(
        PaperRow(
            "Clustering accuracy",
            "clustering",
            said("clustering accuracy", "not reported for this domain"),
            "—"
            if h["accuracy"] is None
            else h["accuracy"]
            + ("" if h["ceiling"] is None else f" (supervised ceiling {h['ceiling']})"),
        )
    )
    rows.append(
        PaperRow(
            "Fig. 4: accuracy vs p",
            "fig4",
            said("", "PCPG above No Clustering at every p"),
            f"PCPG above No Clustering at {h['wins']} of {h['compared']} p values"
            if h["compared"]
            else "—",
        )
    )
    dist = [metrics.get(f"reward_distance/style{s}") for s in range(16)]
    rnd = [metrics.get(f"random/reward_distance/style{s}") for s in range(16)]

    def by_style(values: list) -> str:  # R1, R2, ... in place: a style no cluster stands for is "—"
        n = max((i + 1 for i, v in enumerate(values) if v is not None), default=0)
        return " / ".join("—" if v is None else f"{v:.2f}" for v in values[:n])

    lengths = _env_tables(summary, envs, "rollout_length")
    # rollouts without distances: the domain has no per-style rewards or optimal returns to measure them
    absent = "— (no reward-distance hooks for this domain)" if lengths else "— (no rollouts)"
    rows.append(
        PaperRow(
            "Table 3: reward distance to the optimum, PCPG",
            f"{first}-reward",
            said("reward distance, PCPG (Table 3)", "not reported for this domain"),
            by_style(dist) or absent,
        )
    )
    rows.append(
        PaperRow(
            "Table 3: reward distance to the optimum, random",
            f"{first}-reward",
            said("reward distance, random (Table 3)", "not reported for this domain"),
            by_style(rnd) or absent,
        )
    )
    ours = cross_summary(summary, envs)
    rows.append(
        PaperRow(
            "Table 4: accuracy of π_k on H_k' (mean over p)",
            f"{first}-cross",
            said("cross-accuracy diagonal (Table 4)", "strongest on the diagonal"),
            ours,
        )
    )
    rows.append(
        PaperRow(
            "Figs. 5 and 6: rollout length vs p",
            f"{first}-rollout_length",
            said(
                "",
                "longer with higher p; styles converge to different lengths, No Clustering to one",
            ),
            length_summary(lengths) if lengths else "— (no rollouts)",
        )
    )
    corr = metrics.get("correlation/diagonal_mean")
    rows.append(
        PaperRow(
            "Fig. 7: model vs subset correlation",
            f"{first}-correlation",
            said("", "each model correlates most with its own subset"),
            "—"
            if corr is None
            else f"mean diagonal correlation {corr:.2f}"
            + (
                f"; the diagonal is {_row_max(c)}"
                if (c := _matrices(summary, envs, "correlation"))
                else ""
            ),
        )
    )
    drawn = any(inside(summary / e / "rollouts.png", summary) for e in envs)
    rows.append(
        PaperRow(
            "Fig. 8: one rollout per style",
            f"{first}-rollouts",
            said("", "one rollout per style drawn on the grid"),
            "drawn below" if drawn else "— (the domain draws no rollouts)",
        )
    )
    corruption = _env_tables(summary, envs, "corruption_accuracy")
    ours = "—"
    if corruption:
        d = pd.concat(corruption).groupby("c")[["mean", "std"]].mean()
        ours = " ; ".join(f"c={c:g}: {r['mean']:.3f} ± {r['std']:.3f}" for c, r in d.iterrows())
        nc = metrics.get("corruption/baseline/accuracy")
        if nc is not None:
            ours += f" (No Clustering {nc:.3f})"
    rows.append(
        PaperRow(
            "Fig. 9: accuracy vs label corruption",
            f"{first}-corruption",
            said("", "falls toward No Clustering as c rises; the spread grows"),
            ours,
        )
    )
    rewards = _env_tables(summary, envs, "corruption_reward")
    ours = "—"
    if rewards:  # the spread across one environment's clusters, then the mean over environments
        rcols = [c for c in rewards[0].columns if c.startswith("R") and not c.endswith("_std")]
        spread = pd.concat(
            [
                d.groupby("c")[[c for c in rcols if c in d]].std(ddof=0).mean(axis=1)
                for d in rewards
            ],
            axis=1,
        ).mean(axis=1)
        ours = "spread of subset rewards across an environment's clusters: " + " ; ".join(
            f"c={c:g}: {v:.1f}" for c, v in spread.items()
        )
    rows.append(
        PaperRow(
            "Table 5: subset rewards under label corruption",
            f"{first}-corruption_reward",
            said("", "subsets' rewards become alike as c rises"),
            ours,
        )
    )
    return rows
