"""Which partition does a mixture of policies prefer, the true styles or the default's? Every game.

    uv run python -m benchmarks.zoo.objective [GAME ...] [--seed 0] [--workers 2] [--out F]

For each game: the default clustering (``bag_auto``, k = its styles, its confidence refits
included, one torch thread) at ``--seed``, and the true styles. Each partition is scored as
``benchmarks.zoo.search`` scores one: a fresh policy mixture fitted to it for ``--steps`` Adam
steps (to a sample of at most ``--rows`` steps on large logs), then the mean log-likelihood a
step of each trajectory's actions under its own cluster's policy, in-sample (``fit``) and on
trajectories left out of the fit (``held_out``, 2-fold), averaged over ``--score-seeds``
network seeds. Both partitions get the same network, inputs and training, so neither is favoured.

Where the styles score higher on both, the objective the default climbs (the actions'
likelihood under k policies) prefers the styles, and its gap is its search's. Where the default's
partition scores at least as well on both, no search on that objective would move towards the
styles: the gap is the objective's (the styles are not the k-policy partition that explains the
play best). The held-out games are printed apart; nothing here chooses a setting.
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from benchmarks.zoo.common import game_names, load_game
from benchmarks.zoo.confidence import WITHIN


def objective_row(name: str, seed: int, steps: int, rows: int, score_seeds: int) -> dict:
    """The default's partition of ``name`` at ``seed`` and the styles, each scored."""
    from benchmarks.zoo.check import labelled_dataset
    from benchmarks.zoo.search import partition_scores
    from pcpg_dist.common.devices import set_threads
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import cluster, clustering_metrics

    set_threads(1)
    game = load_game(name)
    ds = labelled_dataset(name, False)
    k = len(game.styles)
    t0 = time.perf_counter()
    labels = cluster(ds, ClusterConfig(k=k), seed).labels
    fit_seconds = time.perf_counter() - t0
    truth = np.asarray(ds.styles, np.int64)

    def scored(partition: np.ndarray) -> dict:
        runs = [partition_scores(ds, partition, k, steps, s, rows) for s in range(score_seeds)]
        return {key: float(np.mean([r[key] for r in runs])) for key in ("fit", "held_out")}

    t0 = time.perf_counter()
    default, styles = scored(labels), scored(truth)
    return {
        "game": name,
        "held_out": game.held_out,
        "blind": game.blind,
        "seed": seed,
        "accuracy": float(clustering_metrics(truth, labels)["accuracy"]),
        "default": default,
        "styles": styles,
        "fit_seconds": fit_seconds,
        "score_seconds": time.perf_counter() - t0,
    }


def reading(row: dict, gap: float | None) -> str:
    """Whose limit the row shows: "at the ceiling", "search" (the styles score higher in and out
    of sample), "objective" (the default's partition scores at least as well on both), "mixed"."""
    if gap is not None and gap <= WITHIN:
        return "at the ceiling"
    better = [row["styles"][m] > row["default"][m] for m in ("fit", "held_out")]
    return "search" if all(better) else "objective" if not any(better) else "mixed"


def ceilings(path: Path | None, seed: int) -> dict[str, float]:
    """Each game's gap at ``seed`` from a ``benchmarks.zoo.confidence`` results file, if given."""
    if path is None or not path.exists():
        return {}
    rows = json.loads(path.read_text())["rows"]
    return {r["game"]: r["gap"] for r in rows if r["seed"] == seed}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("games", nargs="*")
    ap.add_argument("--seed", type=int, default=0, help="the default clustering's seed")
    ap.add_argument("--steps", type=int, default=400, help="Adam steps of each scoring fit")
    ap.add_argument("--rows", type=int, default=32768, help="steps a scoring fit sees at most")
    ap.add_argument("--score-seeds", type=int, default=2, help="scoring networks per partition")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--gaps",
        type=Path,
        default=Path("benchmarks/zoo/confidence_results.json"),
        help="the one table's confidence results: each game's gap at --seed",
    )
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    gaps = ceilings(args.gaps, args.seed)
    names = args.games or game_names()
    with ProcessPoolExecutor(args.workers) as pool:
        jobs = [
            pool.submit(objective_row, n, args.seed, args.steps, args.rows, args.score_seeds)
            for n in names
        ]
        rows = [job.result() for job in as_completed(jobs)]
    print("| game | accuracy | gap | fit: styles / default | held out: styles / default | limit |")
    print("|---|---|---|---|---|---|")
    for row in sorted(rows, key=lambda r: (r["held_out"], r["game"])):
        gap = gaps.get(row["game"])
        row["reading"] = reading(row, gap)
        s, d = row["styles"], row["default"]
        name = row["game"] + (" (held out)" if row["held_out"] else "")
        print(
            f"| {name} | {row['accuracy']:.3f} | "
            f"{'' if gap is None else f'{gap:+.3f}'} | {s['fit']:.4f} / {d['fit']:.4f} | "
            f"{s['held_out']:.4f} / {d['held_out']:.4f} | {row['reading']} |",
            flush=True,
        )
    if args.out:
        settings = {key: str(v) if isinstance(v, Path) else v for key, v in vars(args).items()}
        args.out.write_text(json.dumps({"args": settings, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
