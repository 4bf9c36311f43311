"""The paper beside the run: its protocol (what a run must use to be a reproduction), the
headline numbers, and for every table and figure the paper has what it reports and what this run
measured. Numbers and domain settings come from the domain's ``paper`` (PaperResults: None where
the paper has no results for it); where the paper states a finding rather
than a number (../shared/PAPER.md), the finding.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pandas as pd

from pcpg_dist.config import ExperimentConfig
from pcpg_dist.config.stages import RankConfig
from pcpg_dist.domains.base import PaperResults
from pcpg_dist.reporting.formatting import fmt
from pcpg_dist.reporting.report_data import PaperRow, inside
from pcpg_dist.reporting.run_measures import (
    cross_summary,
    env_tables,
    length_summary,
    matrices,
    row_max,
)
from pcpg_dist.stages.clustering.confidence import verdict_of

#: the paper's protocol for every domain, checked against a run's config: (key, paper value); a
#: domain's own settings are its ``paper.protocol`` (:class:`~pcpg_dist.domains.base.PaperResults`)
PROTOCOL: tuple[tuple[str, object], ...] = (
    ("seeds", 4),  # compared by count: the paper reports 4 seeds
    ("ranking.ps", [1.0, 0.75, 0.5, 0.25, 0.1]),
    ("ranking.beta", 0.1),
    ("ranking.style_margin", 0.0),
    ("clustering.method", "lstm_dec"),
    ("bc.hidden_layers", 3),
    ("bc.hidden_size", 5),
    ("bc.epochs", 2000),
    ("bc.batch_size", None),  # full batch
    ("bc.stop_tol", 0.0),  # every cell all its epochs
    ("bc.init", "scratch"),  # every agent from its own initialisation
)
#: how the report names a paper setting whose value alone would not say it
PAPER_MEANS = {"bc.batch_size": "none (full batch)", "bc.stop_tol": "0 (no early stopping)"}

#: a protocol setting added after runs were logged: a recorded config without it ran with its default
ABSENT_MEANS = {
    "ranking.style_margin": RankConfig.model_fields["style_margin"].default,
    "bc.init": "scratch",  # the only behaviour before init existed
    "bc.stop_tol": 0.0,  # before early stopping existed
}

#: the domain of a recorded config that names none
DEFAULT_DOMAIN = ExperimentConfig.model_fields["domain"].default


def paper_results(domain: str | None) -> PaperResults | None:
    """What the paper reports for a domain; None where it has no results for it, or the domain is
    not installed here."""
    from pcpg_dist.common.errors import PcpgError
    from pcpg_dist.domains import registry

    try:
        return registry.get(str(domain)).paper
    except PcpgError:
        return None


def in_paper(domain: str | None) -> bool:
    """Whether the paper has results for ``domain``."""
    return paper_results(domain) is not None


class PaperDomains:
    """The domains the paper has results for, asked one at a time: ``domain in PAPER_DOMAINS``."""

    def __contains__(self, domain: object) -> bool:
        return in_paper(str(domain))


#: domains the paper has results for (others get no paper column and a banner saying so)
PAPER_DOMAINS = PaperDomains()


# ----------------------------------------------------------------------------- content
def paper_numbers(domain: str | None) -> dict[str, str]:
    """The paper's figures for a domain (none for a domain that is not installed here)."""
    paper = paper_results(domain)
    return {} if paper is None else dict(paper.numbers)


def _get(cfg: dict, key: str):
    value = cfg
    for part in key.split("."):
        if not isinstance(value, dict) or part not in value:
            return None
        value = value[part]
    return value


def protocol_differences(cfg: dict) -> list[tuple[str, str, str]]:
    """(setting, this run, the paper) for every protocol setting the config changes."""
    results = paper_results(cfg.get("domain", DEFAULT_DOMAIN))
    protocol = (*PROTOCOL, *(results.protocol if results is not None else ()))
    absent = {**ABSENT_MEANS, **(results.absent_means if results is not None else {})}
    out = []
    for key, paper in protocol:
        ours = _get(cfg, key)
        if ours is None:
            ours = absent.get(key)
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
        "confidence": verdict_of(metrics).line() if "clustering/stability" in metrics else None,
    }


def paper_rows(domain: str, metrics: dict, summary: Path, envs: list[str]) -> list[PaperRow]:
    """Every table and figure of the paper: what the paper reports and what this run measured."""
    paper = paper_numbers(domain)
    reported = in_paper(domain)
    first = envs[0] if envs else ""

    def said(key: str, finding: str) -> str:
        if not reported:
            return "not in the paper (domain " + domain + ")"
        return paper.get(key, finding)

    lengths = env_tables(summary, envs, "rollout_length")
    return [
        *_headline_rows(metrics, said),
        *_reward_distance_rows(metrics, first, said, bool(lengths)),
        PaperRow(
            "Table 4: accuracy of π_k on H_k' (mean over p)",
            f"{first}-cross",
            said("cross-accuracy diagonal (Table 4)", "strongest on the diagonal"),
            cross_summary(summary, envs),
        ),
        PaperRow(
            "Figs. 5 and 6: rollout length vs p",
            f"{first}-rollout_length",
            said(
                "",
                "longer with higher p; styles converge to different lengths, No Clustering to one",
            ),
            length_summary(lengths) if lengths else "— (no rollouts)",
        ),
        _correlation_row(metrics, summary, envs, first, said),
        PaperRow(
            "Fig. 8: one rollout per style",
            f"{first}-rollouts",
            said("", "one rollout per style drawn on the grid"),
            "drawn below"
            if any(inside(summary / e / "rollouts.png", summary) for e in envs)
            else "— (the domain draws no rollouts)",
        ),
        PaperRow(
            "Fig. 9: accuracy vs label corruption",
            f"{first}-corruption",
            said("", "falls toward No Clustering as c rises; the spread grows"),
            _corruption_accuracy(metrics, summary, envs),
        ),
        PaperRow(
            "Table 5: subset rewards under label corruption",
            f"{first}-corruption_reward",
            said("", "subsets' rewards become alike as c rises"),
            _corruption_rewards(summary, envs),
        ),
    ]


#: what the paper says of an item: (the key of its number, the finding where it states no number)
Said = Callable[[str, str], str]


def _headline_rows(metrics: dict, said: Said) -> list[PaperRow]:
    """Clustering accuracy (with the supervised ceiling) and Fig. 4 (PCPG ahead at how many p)."""
    h = headline(metrics)
    return [
        PaperRow(
            "Clustering accuracy",
            "clustering",
            said("clustering accuracy", "not reported for this domain"),
            "—"
            if h["accuracy"] is None
            else h["accuracy"]
            + ("" if h["ceiling"] is None else f" (supervised ceiling {h['ceiling']})"),
        ),
        *(
            [
                PaperRow(
                    "Label-free confidence",
                    "clustering",
                    said("", "not part of the paper: refits on subsamples, no labels used"),
                    h["confidence"],
                )
            ]
            if h["confidence"]
            else []
        ),
        PaperRow(
            "Fig. 4: accuracy vs p",
            "fig4",
            said("", "PCPG above No Clustering at every p"),
            f"PCPG above No Clustering at {h['wins']} of {h['compared']} p values"
            if h["compared"]
            else "—",
        ),
    ]


def _reward_distance_rows(metrics: dict, first: str, said: Said, rollouts: bool) -> list[PaperRow]:
    """Table 3's two rows: the reward distance to the optimum by style, PCPG's and random's."""
    dist = [metrics.get(f"reward_distance/style{s}") for s in range(16)]
    rnd = [metrics.get(f"random/reward_distance/style{s}") for s in range(16)]

    def by_style(values: list) -> str:  # R1, R2, ... in place: a style no cluster stands for is "—"
        n = max((i + 1 for i, v in enumerate(values) if v is not None), default=0)
        return " / ".join("—" if v is None else f"{v:.2f}" for v in values[:n])

    # rollouts without distances: the domain has no per-style rewards or optimal returns to measure them
    absent = "— (no reward-distance hooks for this domain)" if rollouts else "— (no rollouts)"
    return [
        PaperRow(
            "Table 3: reward distance to the optimum, PCPG",
            f"{first}-reward",
            said("reward distance, PCPG (Table 3)", "not reported for this domain"),
            by_style(dist) or absent,
        ),
        PaperRow(
            "Table 3: reward distance to the optimum, random",
            f"{first}-reward",
            said("reward distance, random (Table 3)", "not reported for this domain"),
            by_style(rnd) or absent,
        ),
    ]


def _correlation_row(
    metrics: dict, summary: Path, envs: list[str], first: str, said: Said
) -> PaperRow:
    """Fig. 7: the mean diagonal correlation and where each row's maximum lies."""
    corr = metrics.get("correlation/diagonal_mean")
    return PaperRow(
        "Fig. 7: model vs subset correlation",
        f"{first}-correlation",
        said("", "each model correlates most with its own subset"),
        "—"
        if corr is None
        else f"mean diagonal correlation {corr:.2f}"
        + (
            f"; the diagonal is {row_max(c)}"
            if (c := matrices(summary, envs, "correlation"))
            else ""
        ),
    )


def _corruption_accuracy(metrics: dict, summary: Path, envs: list[str]) -> str:
    """Fig. 9: the accuracy at each corruption level c (mean ± std over environments)."""
    corruption = env_tables(summary, envs, "corruption_accuracy")
    ours = "—"
    if corruption:
        d = pd.concat(corruption).groupby("c")[["mean", "std"]].mean()
        ours = " ; ".join(f"c={c:g}: {r['mean']:.3f} ± {r['std']:.3f}" for c, r in d.iterrows())
        nc = metrics.get("corruption/baseline/accuracy")
        if nc is not None:
            ours += f" (No Clustering {nc:.3f})"
    return ours


def _corruption_rewards(summary: Path, envs: list[str]) -> str:
    """Table 5: the spread across one environment's clusters, then the mean over environments."""
    rewards = env_tables(summary, envs, "corruption_reward")
    if not rewards:
        return "—"
    rcols = [c for c in rewards[0].columns if c.startswith("R") and not c.endswith("_std")]
    spread = pd.concat(
        [d.groupby("c")[[c for c in rcols if c in d]].std(ddof=0).mean(axis=1) for d in rewards],
        axis=1,
    ).mean(axis=1)
    return "spread of subset rewards across an environment's clusters: " + " ; ".join(
        f"c={c:g}: {v:.1f}" for c, v in spread.items()
    )
