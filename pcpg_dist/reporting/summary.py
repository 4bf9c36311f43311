"""Across environments: summary metrics, tables, a figure, and the terminal summary table."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from pcpg_dist.common.files import atomic_write_bytes
from pcpg_dist.stages.clustering.confidence import verdict_of
from pcpg_dist.stages.figures import accuracy_figure


def _mean(values: list[float]) -> float:
    vals = [v for v in values if v == v]
    return float(np.mean(vals)) if vals else float("nan")


def summary_metrics(
    per_env: dict[str, dict[str, float]], clusters: dict[str, dict[str, float]]
) -> dict[str, float]:
    """Each metric's mean over environments, plus ``<env>/<metric>`` for every environment."""
    merged = {e: {**clusters.get(e, {}), **m} for e, m in per_env.items()}
    names = sorted({k for m in merged.values() for k in m})
    out = {n: _mean([m[n] for m in merged.values() if n in m]) for n in names}
    for env, m in merged.items():
        out.update({f"{env}/{k}": v for k, v in m.items()})
    return out


def accuracy_table(per_env: dict[str, dict[str, float]], ps: tuple[float, ...]) -> pd.DataFrame:
    rows = []
    for env, m in per_env.items():
        for p in ps:
            rows.append(
                {
                    "env": env,
                    "p": p,
                    "pcpg": m.get(f"pcpg/accuracy/p{p:g}", np.nan),
                    "pcpg_std": m.get(f"pcpg/accuracy/p{p:g}/std", np.nan),
                    "no_clustering": m.get(f"baseline/accuracy/p{p:g}", np.nan),
                    "no_clustering_std": m.get(f"baseline/accuracy/p{p:g}/std", np.nan),
                    # on the same rows as PCPG at this p, like the majority class
                    "random": m.get(f"random/accuracy/p{p:g}", np.nan),
                    "majority": m.get(f"majority/accuracy/p{p:g}", np.nan),
                }
            )
    return pd.DataFrame(rows)


def write_summary(
    cfg,
    summary: Path,
    eval_dirs: dict[str, Path],
    per_env: dict[str, dict[str, float]],
    clusters: dict[str, dict[str, float]],
) -> dict[str, float]:
    """Write a new ``summary`` folder (metrics, tables, figures, per-environment folders); return
    metrics. The folder must not exist: the runner builds it aside and swaps it in when complete
    (:func:`pcpg_dist.api.finish.finish_point`), so a killed write never mixes two runs' files."""
    summary = Path(summary)
    summary.mkdir(parents=True)
    metrics = summary_metrics(per_env, clusters)
    atomic_write_bytes(
        summary / "metrics.json", json.dumps(metrics, indent=1, sort_keys=True).encode()
    )
    acc = accuracy_table(per_env, cfg.ranking.ps)
    acc.to_csv(summary / "accuracy_vs_p.csv", index=False)
    acc.to_json(summary / "accuracy_vs_p.json", orient="records", indent=1)
    clus = pd.DataFrame([{"env": e, **m} for e, m in clusters.items()])
    clus.to_csv(summary / "clustering.csv", index=False)
    clus.to_json(summary / "clustering.json", orient="records", indent=1)
    for env, d in eval_dirs.items():
        shutil.copytree(d, summary / env, ignore=shutil.ignore_patterns("done.json"))
    accuracy_figure(acc, summary / "accuracy_vs_p.png")
    return metrics


def _lead(m: dict, p: float) -> str:
    """PCPG's lead over No Clustering at ``p`` and one seed's paired standard error (trajectories
    as the units; ``pcpg/lead_over_nc*``), or "-" where the run has none."""
    lead, se = m.get(f"pcpg/lead_over_nc/p{p:g}"), m.get(f"pcpg/lead_over_nc_se/p{p:g}")
    if lead is None:
        return "-"
    return f"{lead:+.3f}" + ("" if se is None or np.isnan(se) else f" ± {se:.3f}")


def print_summary(result, console, method: str | None = None, bc=None) -> None:
    """The terminal summary: accuracy per p (PCPG vs No Clustering), clustering quality (with the
    clustering ``method`` each environment was clustered with, where given), how the agents of
    units whose verdict doubts their styles started (with the run's ``bc`` config), times."""
    from rich.table import Table

    m = result.metrics
    ps = sorted(
        {
            float(k.split("/p")[1].split("/")[0])
            for k in m
            if k.startswith("pcpg/accuracy/p") and k.count("/") == 2
        },
        reverse=True,
    )
    t = Table(title="Accuracy on held-out trajectories (mean over environments)")
    t.add_column("p", justify="right")
    t.add_column("PCPG", justify="right")
    t.add_column("No Clustering", justify="right")
    t.add_column("PCPG - NC (± s.e.)", justify="right")
    t.add_column("majority class", justify="right")
    t.add_column("random", justify="right")
    for p in ps:
        t.add_row(
            f"{p:g}",
            f"{m.get(f'pcpg/accuracy/p{p:g}', float('nan')):.3f}",
            f"{m.get(f'baseline/accuracy/p{p:g}', float('nan')):.3f}",
            _lead(m, p),
            f"{m.get(f'majority/accuracy/p{p:g}', float('nan')):.3f}",
            f"{m.get(f'random/accuracy/p{p:g}', float('nan')):.3f}",
        )
    console.print(t)
    print_clustering(result, console, method)
    _print_weights(result, console)
    _print_starts(result, console, bc)
    if "cross/diagonal_mean" in m:
        console.print(
            "each cluster's agent on its own cluster's held-out trajectories (the cross-accuracy "
            f"diagonal, Table 4): {m['cross/diagonal_mean']:.3f} (cross/diagonal_mean)"
        )
    distances = [
        f"{k.split('/')[1]} {m[k]:.2f}"
        for k in sorted(m)
        if k.startswith("reward_distance/style") and k.count("/") == 1
    ]
    if distances:
        console.print(
            "distance to the optimal reward under each style's R_k (Table 3, reward_distance/): "
            + ", ".join(distances)
        )
    console.print(stage_times(result))


def _print_weights(result, console) -> None:
    """For each environment clustered by its moves' features (``choice_mix``), what sets each
    cluster apart: the features whose weight differs most from the clusters' mean."""
    from pcpg_dist.stages.clustering.style_weights import apart_line

    for env in result.clustering:
        path = Path(result.out_dir) / "summary" / env / "style_weights.csv"
        if path.is_file():
            console.print(apart_line(env, pd.read_csv(path)), markup=False, highlight=False)


def _print_starts(result, console, bc) -> None:
    """Under ``bc.init: auto``, which environments' per-cluster agents were fine-tuned from the
    No Clustering agent (their verdict doubts the styles) and how."""
    if bc is None or bc.init != "auto":
        return
    doubted = [e for e, cm in result.clustering.items() if verdict_of(cm).doubts_styles]
    if not doubted:
        return
    kept = (
        ", each fine-tune kept only where it won a trial on held-out steps of its cluster"
        " (bc.finetune_check)"
        if bc.finetune_check > 0
        else ""
    )
    console.print(
        f"{', '.join(doubted)}: the verdict doubts the styles, so each per-cluster agent was "
        f"fine-tuned from the No Clustering agent (bc.init: auto){kept}; "
        "docs/bc_and_evaluation.md"
    )


def print_clustering(result, console, method: str | None = None) -> None:
    """The clustering table: quality against the true styles where known, the method used, and
    the label-free confidence (stability under resampling, its verdict and warnings)."""
    from rich.table import Table

    c = Table(title="Clustering")
    cols = [
        k
        for k in (
            "ari",
            "nmi",
            "accuracy",
            "ceiling",
            "gap_to_ceiling",
            "silhouette",
            "stability",
            "fit_seconds",
        )
        if any(f"clustering/{k}" in v for v in result.clustering.values())
    ]
    judged = "stability" in cols and any(
        "clustering/stability" in v for v in result.clustering.values()
    )
    c.add_column("env")
    if method:
        c.add_column("method")
    shown = {
        "gap_to_ceiling": "gap",
        "silhouette": "silh.",
        "stability": "stab.",
        "fit_seconds": "fit s",
    }
    for k in cols:
        c.add_column(shown.get(k, k), justify="right")
    if judged:
        c.add_column("confidence (no labels)")
    for env, cm in result.clustering.items():
        used = [method_used(method, cm)] if method else []
        said = [verdict_of(cm).verdict] if judged else []
        c.add_row(
            env, *used, *[f"{cm.get(f'clustering/{k}', float('nan')):.3f}" for k in cols], *said
        )
    console.print(c)
    for env, cm in result.clustering.items():
        merged = [r for r in verdict_of(cm).reasons if r.endswith("look like one style")]
        if merged:
            console.print(f"{env}: {merged[0]} (the refits on subsamples mostly join them)")
    fell = [e for e, cm in result.clustering.items() if cm.get(FELL_BACK)]
    if method and fell:
        console.print(
            f"{method} clustered {', '.join(fell)} with "
            f"{method_used(method, {FELL_BACK: 1}).split(' -> ')[-1]}: "
            "most of their states occur once (continuous states), so visitation bags hold no "
            "style; a mixture of neural policies still sees which action each style takes "
            "where (docs/zoo.md)"
        )
    for env, cm in result.clustering.items():
        if method and cm.get(TIMED):
            console.print(
                f"{method} clustered {env} with policy_mix seeing the time step: its clusters "
                "came back on subsamples (stability "
                f"{cm.get('clustering/auto_stability_policy_mix_time', float('nan')):.2f}) where "
                "those of policies of the state alone did not "
                f"({cm.get('clustering/auto_stability_policy_mix', float('nan')):.2f}; docs/zoo.md)"
            )
        elif method and cm.get(CHOSE):
            console.print(
                f"{method} clustered {env} with policy_mix: its clusters came back on subsamples "
                f"(stability {cm.get('clustering/auto_stability_policy_mix', float('nan')):.2f}) "
                "where greedy_mix's did not "
                f"({cm.get('clustering/auto_stability_greedy_mix', float('nan')):.2f}; docs/zoo.md)"
            )


FELL_BACK = "clustering/auto_fell_back"
CHOSE = "clustering/auto_chose_policy_mix"
TIMED = "clustering/auto_chose_policy_time"
BY_MOVES = "clustering/auto_chose_choice_mix"


def method_used(method: str, clustering: dict[str, float]) -> str:
    """The method that clustered an environment: the configured one, or where it handed the
    data to its fallback, both (``bag_auto -> policy_mix``)."""
    from pcpg_dist.config.clusterers import CLUSTERERS

    fallback = CLUSTERERS[method].continuous_fallback if method in CLUSTERERS else None
    if clustering.get("clustering/auto_fell_back_to_lstm"):
        fallback = "lstm_dec"  # the log's actions said nothing (auto.fallback_for)
    timed = " (time)" if clustering.get(TIMED) else ""  # its policies see the step (select.py)
    if clustering.get(BY_MOVES):
        return f"{method} -> choice_mix"  # the user gave the moves' features (auto.by_moves)
    if clustering.get(CHOSE):
        return f"{method} -> policy_mix{timed}"  # the more stable on discrete states (select.py)
    if clustering.get(FELL_BACK) and fallback:
        return f"{method} -> {fallback}{timed}"
    return method


def stage_times(result) -> str:
    """``time per stage: ...`` for the stages this run computed; the ones served from the cache are
    named as such (their recorded seconds are those of the run that computed them)."""
    cached = list(getattr(result, "cached_stages", []) or [])
    ran = ", ".join(f"{k} {v:.1f}s" for k, v in result.stage_seconds.items() if k not in cached)
    line = f"time per stage: {ran or 'none'}"
    return f"{line}; from the cache: {', '.join(cached)}" if cached else line
