"""Score the clusterers on the zoo: each game's ceiling (the supervised panel), each method's
clustering accuracy and seconds, the default's gap; held-out games reported apart.

    uv run python -m benchmarks.zoo.evaluate --out zoo_results.json --markdown docs/zoo.md
    uv run python -m benchmarks.zoo.evaluate cartpole pong --ci      # a quick look

Every game is built from its generator (``--ci``: the small counts), read back through pcpg's
own step-table reader, clustered with k = its number of styles by each method (seed 0), and the
cheapest clustering is repeated on the unlabelled copy (styles -1) to check a user without labels
gets the same clusters.
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from benchmarks.zoo.common import game_names, load_game

METHODS = ("bag_auto", "policy_mix", "visits_kmeans", "summary_kmeans")
DEFAULT = "bag_auto"


def score_dataset(ds, k: int, methods: tuple[str, ...], seed: int = 0) -> dict:
    """The ceiling panel and every method's accuracy and seconds on one labelled dataset."""
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import cluster, clustering_metrics
    from pcpg_dist.stages.clustering.ceiling import ceiling_panel

    t0 = time.perf_counter()
    panel = ceiling_panel(ds, seed=seed)
    row = {
        "ceiling": max(panel.values()),
        "panel": panel,
        "ceiling_seconds": time.perf_counter() - t0,
    }
    row["methods"] = {}
    for method in methods:
        t0 = time.perf_counter()
        result = cluster(ds, ClusterConfig(method=method, k=k), seed)
        labels = np.asarray(result.labels)
        row["methods"][method] = {
            "accuracy": float(clustering_metrics(ds.styles, labels)["accuracy"]),
            "seconds": time.perf_counter() - t0,
            "fell_back": bool(result.metrics.get("auto_fell_back", 0)),
            "labels": labels.tolist(),
        }
    return row


def score_game(name: str, ci: bool, methods: tuple[str, ...]) -> dict:
    from benchmarks.zoo.check import labelled_dataset
    from pcpg_dist.common.devices import set_threads

    set_threads(1)  # one worker process per core: more torch threads than CPUs is ~100x slower

    game = load_game(name)
    t0 = time.perf_counter()
    ds = labelled_dataset(name, ci)
    built = time.perf_counter() - t0
    row = score_dataset(ds, len(game.styles), methods)
    row.update(
        game=name,
        package=game.package,
        kinds=list(game.kinds),
        held_out=game.held_out,
        trajectories=ds.n_trajectories,
        steps=int((ds.actions >= 0).sum()),
        build_seconds=built,
    )
    # the unlabelled copy (styles -1), as a user without labels has it: Step A never reads
    # styles, so its clusters must be the same (checked with the cheapest method)
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import cluster

    cheap = "visits_kmeans" if "visits_kmeans" in methods else DEFAULT
    blind = ds.with_styles(np.full(ds.n_trajectories, -1))
    labels = cluster(blind, ClusterConfig(method=cheap, k=len(game.styles)), 0).labels
    row["unlabelled_same"] = bool(np.array_equal(labels, row["methods"][cheap]["labels"]))
    for m in row["methods"].values():
        del m["labels"]
    return row


def markdown(rows: list[dict], methods: tuple[str, ...]) -> str:
    """docs/zoo.md's tables: design games, then held-out games."""
    head = "| game | package | kinds | n | ceiling | " + " | ".join(methods)
    head += f" | default ({DEFAULT}) gap | default s |\n|" + "---|" * (len(methods) + 7) + "\n"
    parts = []
    for title, held in (("Design games", False), ("Held-out games", True)):
        mine = [r for r in rows if r["held_out"] == held]
        if not mine:
            continue
        lines = []
        for r in mine:
            accs = " | ".join(f"{r['methods'][m]['accuracy']:.3f}" for m in methods)
            d = r["methods"][DEFAULT]
            gap = r["ceiling"] - d["accuracy"]
            note = " (fell back)" if d["fell_back"] else ""
            lines.append(
                f"| {r['game']} | {r['package']} | {', '.join(r['kinds'])} | {r['trajectories']} | "
                f"{r['ceiling']:.3f} | {accs} | {gap:+.3f}{note} | {d['seconds']:.1f} |"
            )
        gaps = [r["ceiling"] - r["methods"][DEFAULT]["accuracy"] for r in mine]
        parts.append(
            f"### {title}\n\n{head}"
            + "\n".join(lines)
            + f"\n\nMean gap of the default: {np.mean(gaps):+.3f}; largest {max(gaps):+.3f}.\n"
        )
    return "\n".join(parts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("games", nargs="*", help="game folders (default: all)")
    ap.add_argument("--ci", action="store_true", help="the small counts")
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--out", type=Path, default=None, help="results as JSON")
    ap.add_argument("--markdown", type=Path, default=None, help="write the tables here")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    methods = tuple(args.methods.split(","))
    if DEFAULT not in methods:
        methods = (DEFAULT, *methods)
    names = args.games or game_names()
    rows = []
    with ProcessPoolExecutor(args.workers) as pool:
        jobs = [pool.submit(score_game, n, args.ci, methods) for n in names]
        for job in as_completed(jobs):
            row = job.result()
            d = row["methods"][DEFAULT]
            print(
                f"{row['game']:<22} ceiling {row['ceiling']:.3f} default {d['accuracy']:.3f} "
                + " ".join(f"{m} {v['accuracy']:.3f}" for m, v in row["methods"].items())
                + f"  unlabelled same: {row['unlabelled_same']}",
                flush=True,
            )
            rows.append(row)
            if args.out:  # after every game: a long evaluation keeps what it measured
                args.out.write_text(json.dumps(rows, indent=1))
    if args.markdown:
        args.markdown.write_text(markdown(rows, methods))


if __name__ == "__main__":
    main()
