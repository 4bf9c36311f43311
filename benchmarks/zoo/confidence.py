"""Does the label-free confidence track the true gap? For every zoo game: the default clusterer,
its stability under resampling (pcpg_dist/stages/clustering/confidence.py), its verdict, and the
gap to the supervised ceiling that only labels can tell; then the rank correlation between
stability and the gap, and how often the verdict "styles found" agrees with "gap <= 5 points"
(design games and held-out games apart).

    uv run python -m benchmarks.zoo.confidence --ci --out zoo_confidence.json
    uv run python -m benchmarks.zoo.confidence --reverdict zoo_confidence.json  # new thresholds
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from benchmarks.zoo.common import game_names, load_game, overrides

CLOSE = 0.05  # "at the ceiling": the bar for the verdict
WITHIN = 0.03 + 1e-9  # the bar for the default's gap (3 points; float slack)


def confidence_rows(
    name: str, ci: bool, runs: int, over: dict | None = None, seeds: tuple[int, ...] = (0,)
) -> list[dict]:
    """:func:`confidence_row` of ``name`` at each of ``seeds``; the ceiling's panel is the data's,
    cross-validated once (seed 0), and every seed's gap is measured against it."""
    from benchmarks.zoo.check import labelled_dataset
    from pcpg_dist.common.devices import set_threads
    from pcpg_dist.stages.clustering.ceiling import ceiling_panel

    set_threads(1)
    game = load_game(name)
    ds = labelled_dataset(name, ci)
    panel = ceiling_panel(ds, seed=0, move_features=(over or {}).get("move_features"))
    return [confidence_row(name, game, ds, runs, over, seed, panel) for seed in seeds]


def confidence_row(
    name: str, game, ds, runs: int, over: dict | None, seed: int, panel: dict
) -> dict:
    """The default's accuracy, gap to the ceiling of ``panel``, stability and verdict at ``seed``."""
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import cluster, clustering_metrics
    from pcpg_dist.stages.clustering.confidence import stability, verdict_of

    k = len(game.styles)
    cfg = ClusterConfig(k=k, confidence_runs=runs, **(over or {}))  # over: --set KEY=VALUE
    t0 = time.perf_counter()
    result = cluster(ds, cfg, seed)
    fit = time.perf_counter() - t0
    t0 = time.perf_counter()
    if "stability" in result.metrics:  # bag_auto chose its method by it (select.py)
        found = {k: v for k, v in result.metrics.items() if k.startswith(("stability", "merged"))}
    else:
        found = stability(ds, cfg, seed, result.labels, runs, 0.8)
    refit = time.perf_counter() - t0
    accuracy = clustering_metrics(ds.styles, result.labels)["accuracy"]
    ceiling = max(panel.values())
    metrics = {**result.metrics, **found}
    return {
        "game": name,
        "seed": seed,
        "held_out": game.held_out,
        "n": ds.n_trajectories,
        "ceiling": ceiling,
        "accuracy": float(accuracy),
        "gap": float(ceiling - accuracy),
        **found,
        "verdict": verdict_of(metrics, k).verdict,
        "n_clusters_used": float(result.metrics.get("n_clusters_used", k)),
        "fell_back": bool(result.metrics.get("auto_fell_back", 0)),
        "chose_policy_mix": bool(result.metrics.get("auto_chose_policy_mix", 0)),
        "chose_policy_time": bool(result.metrics.get("auto_chose_policy_time", 0)),
        "panel": panel,
        "fit_seconds": fit,
        "confidence_seconds": refit,
    }


def summary(rows: list[dict]) -> dict:
    """Spearman rank correlation of stability with -gap, and the verdict's agreement with
    "gap <= CLOSE" ("styles found" is the verdict that claims it), over every (game, seed) row;
    with several seeds also the games' mean gaps and how many are within 3 points on average."""
    from scipy.stats import spearmanr

    out = {}
    for part, held in (("design", False), ("held_out", True), ("all", None)):
        mine = [r for r in rows if held is None or r["held_out"] == held]
        if len(mine) < 2:
            continue
        rho = spearmanr([r["stability"] for r in mine], [-r["gap"] for r in mine]).statistic
        agree = [(r["verdict"] == "styles found") == (r["gap"] <= CLOSE) for r in mine]
        games = sorted({r["game"] for r in mine})
        gaps = [np.mean([r["gap"] for r in mine if r["game"] == g]) for g in games]
        out[part] = {
            "games": len(games),
            "rows": len(mine),
            "spearman": float(rho),
            "agreement": float(np.mean(agree)),
            "mean_gap": float(np.mean(gaps)),
            "within_3_points": int(sum(g <= WITHIN for g in gaps)),
        }
    return out


def reverdict(row: dict) -> str:
    """The row's verdict under the current thresholds (its clustering is not rerun). Rows written
    before they kept ``n_clusters_used``: "no evidence" at a stability of at least WEAK can only
    have been a collapse, and is kept."""
    from pcpg_dist.stages.clustering.confidence import WEAK, verdict_of

    used = row.get("n_clusters_used")
    if used is None and row["verdict"].startswith("no evidence") and row["stability"] >= WEAK:
        return row["verdict"]
    metrics = {"stability": row["stability"], "stability_k": row["stability_k"]}
    if used is not None:
        metrics["n_clusters_used"] = used
    return verdict_of(metrics, int(row["stability_k"])).verdict


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("games", nargs="*")
    ap.add_argument("--ci", action="store_true")
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="clustering seeds")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a clustering key other than its default (latent_runs=8), for a measurement",
    )
    ap.add_argument(
        "--reverdict", type=Path, default=None, help="re-derive a results file's verdicts"
    )
    args = ap.parse_args()
    if args.reverdict:
        results = json.loads(args.reverdict.read_text())
        for r in results["rows"]:
            before, r["verdict"] = r["verdict"], reverdict(r)
            if before != r["verdict"]:
                print(f"{r['game']}: stability {r['stability']:.2f}: {before} -> {r['verdict']}")
        results["summary"] = summary(results["rows"])
        args.reverdict.write_text(json.dumps(results, indent=1))
        print(json.dumps(results["summary"], indent=1))
        return
    over = overrides(args.set)
    rows = []
    with ProcessPoolExecutor(args.workers) as pool:
        jobs = [
            pool.submit(confidence_rows, n, args.ci, args.runs, over, tuple(args.seeds))
            for n in args.games or game_names()
        ]
        for job in as_completed(jobs):
            for r in job.result():
                rows.append(r)
                print(
                    f"{r['game']:<20} seed {r['seed']} gap {r['gap']:+.3f} stability "
                    f"{r['stability']:.2f} -> {r['verdict']:<24} "
                    f"({r['fit_seconds']:.0f} s + {r['confidence_seconds']:.0f} s)",
                    flush=True,
                )
            if args.out:
                args.out.write_text(json.dumps({"rows": rows, "summary": summary(rows)}, indent=1))
    print(json.dumps(summary(rows), indent=1))


if __name__ == "__main__":
    main()
