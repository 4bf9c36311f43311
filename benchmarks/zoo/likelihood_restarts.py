"""Restarts chosen by held-out likelihood: would a default that fits several seeds and keeps the
partition its own objective rates best beat one seed?

    uv run python -m benchmarks.zoo.likelihood_restarts [GAME ...] [--seeds 0 1 2] [--out F]
    uv run python -m benchmarks.zoo.likelihood_restarts --held-out [GAME ...] --out F
    uv run python -m benchmarks.zoo.likelihood_restarts --read F

For each game and seed: the default clustering (``bag_auto``, k = its styles, its confidence
refits included, one torch thread), its accuracy against the styles and its stability; then its
partition scored as ``benchmarks.zoo.objective`` scores one (a fresh policy mixture fitted to it,
the actions' mean log-likelihood a step on trajectories left out of the fit, ``--score-seeds``
scoring networks). Per game: seed 0's accuracy, the mean over the seeds, the accuracy of the seed
whose held-out likelihood is highest (what a default that restarts and keeps its likeliest fit
would give; and in-sample, beside it), of the seed whose stability is highest (the eighth session's "restarts kept by
stability"), and of the best seed (what any choice among these seeds could give).

The held-out likelihood is the objective policy_mix climbs, measured where no fit saw the
trajectories, so it needs no labels. Design games by default; ``--held-out`` runs the held-out
games, to be read once a choice is made on the design games.
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from benchmarks.zoo.common import game_names, load_game

#: the design games whose default is not at its ceiling at every seed of the one table
DESIGN = ("highway", "leduc_poker", "minigrid_empty", "minigrid_fourrooms", "pong", "tictactoe")


def seed_row(name: str, seed: int, steps: int, rows: int, score_seeds: int) -> dict:
    """The default's partition of ``name`` at ``seed``: accuracy, stability, held-out score."""
    from benchmarks.zoo.check import labelled_dataset
    from benchmarks.zoo.objective import scored
    from pcpg_dist.common.devices import set_threads
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import cluster, clustering_metrics

    set_threads(1)
    ds = labelled_dataset(name, False)
    k = len(load_game(name).styles)
    t0 = time.perf_counter()
    result = cluster(ds, ClusterConfig(k=k), seed)
    fit_seconds = time.perf_counter() - t0
    truth = np.asarray(ds.styles, np.int64)
    t0 = time.perf_counter()
    scores = scored(ds, result.labels, k, steps, rows, score_seeds)
    return {
        "game": name,
        "held_out": load_game(name).held_out,
        "seed": seed,
        "accuracy": float(clustering_metrics(truth, result.labels)["accuracy"]),
        "stability": float(result.metrics.get("stability", float("nan"))),
        "held_out_score": float(np.mean(scores["held_out"])),
        "fit_score": float(np.mean(scores["fit"])),
        "fit_seconds": fit_seconds,
        "score_seconds": time.perf_counter() - t0,
    }


def chosen(rows: list[dict], key: str) -> dict:
    """The row with the highest ``key`` (ties: the lowest seed)."""
    return max(sorted(rows, key=lambda r: r["seed"]), key=lambda r: r[key])


def summary(rows: list[dict]) -> list[dict]:
    """Per game: seed 0's accuracy, the mean, and the accuracy each choice of seed gives."""
    games: dict[str, list[dict]] = {}
    for r in rows:
        games.setdefault(r["game"], []).append(r)
    out = []
    for name, runs in sorted(games.items(), key=lambda kv: (kv[1][0]["held_out"], kv[0])):
        runs = sorted(runs, key=lambda r: r["seed"])
        acc = [r["accuracy"] for r in runs]
        out.append(
            {
                "game": name,
                "held_out": runs[0]["held_out"],
                "accuracies": acc,
                "held_out_scores": [r["held_out_score"] for r in runs],
                "first": acc[0],
                "mean": float(np.mean(acc)),
                "by_likelihood": chosen(runs, "held_out_score")["accuracy"],
                "by_fit": chosen(runs, "fit_score")["accuracy"],
                "by_stability": chosen(runs, "stability")["accuracy"],
                "best": max(acc),
            }
        )
    return out


def print_summary(rows: list[dict]) -> None:
    print(
        "| game | accuracy at each seed | held-out score at each seed (nats a step) | mean | "
        "kept by likelihood | kept by in-sample likelihood | kept by stability | best seed |"
    )
    print("|---|---|---|---|---|---|---|---|")
    table = summary(rows)
    for g in table:
        name = g["game"] + (" (held out)" if g["held_out"] else "")
        acc = " / ".join(f"{a:.3f}" for a in g["accuracies"])
        score = " / ".join(f"{s:.4f}" for s in g["held_out_scores"])
        print(
            f"| {name} | {acc} | {score} | {g['mean']:.3f} | {g['by_likelihood']:.3f} | "
            f"{g['by_fit']:.3f} | "
            f"{g['by_stability']:.3f} | {g['best']:.3f} |"
        )
    for held_out in (False, True):
        part = [g for g in table if g["held_out"] == held_out]
        if part:
            gain = np.mean([g["by_likelihood"] - g["mean"] for g in part])
            print(
                f"{'held-out' if held_out else 'design'} games: kept by likelihood less the mean "
                f"over seeds {gain:+.3f}; by in-sample likelihood "
                f"{np.mean([g['by_fit'] - g['mean'] for g in part]):+.3f}; by stability "
                f"{np.mean([g['by_stability'] - g['mean'] for g in part]):+.3f}"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("games", nargs="*")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--steps", type=int, default=400, help="Adam steps of each scoring fit")
    ap.add_argument("--rows", type=int, default=32768, help="steps a scoring fit sees at most")
    ap.add_argument("--score-seeds", type=int, default=2, help="scoring networks per partition")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--held-out", action="store_true", help="run the held-out games")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--read", type=Path, default=None, help="print a results file's table again")
    args = ap.parse_args()
    if args.read:
        print_summary(json.loads(args.read.read_text())["rows"])
        return
    held = [g for g in game_names() if load_game(g).held_out]
    games = args.games or (held if args.held_out else list(DESIGN))
    for g in games:
        if g not in game_names():
            ap.error(f"unknown game {g!r}; the zoo has {', '.join(game_names())}")
        if load_game(g).held_out and not args.held_out:
            ap.error(f"{g} is held out: pass --held-out once the choice is made on design games")
    with ProcessPoolExecutor(args.workers) as pool:
        jobs = [
            pool.submit(seed_row, g, s, args.steps, args.rows, args.score_seeds)
            for g in games
            for s in args.seeds
        ]
        rows = []
        for job in as_completed(jobs):
            rows.append(job.result())
            r = rows[-1]
            print(
                f"{r['game']} seed {r['seed']}: accuracy {r['accuracy']:.3f}, held-out score "
                f"{r['held_out_score']:.4f}, {r['fit_seconds']:.0f} + {r['score_seconds']:.0f} s",
                flush=True,
            )
    if args.out:
        args.out.write_text(
            json.dumps({"args": vars(args) | {"out": str(args.out)}, "rows": rows}, indent=1)
        )
    print_summary(rows)


if __name__ == "__main__":
    main()
