"""How many steps must policy_mix's policies be fitted to? The default clustering per game with
``clustering.policy_rows`` (a seeded sample of the log's steps that the policies are fitted to;
every step is still scored) at each value asked, side by side in one run.

    uv run python -m benchmarks.zoo.rows_exp --rows 0 16384 32768            # design games
    uv run python -m benchmarks.zoo.rows_exp --held-out --rows 0 16384       # after the choice

Each row: the default (``bag_auto`` with its label-free confidence, one thread) and its choice,
accuracy against the true styles, stability, and wall seconds; the speed-up is the seconds of
``policy_rows: 0`` (every step) over the seconds of the row. Held-out games take no part in the
choice: ``--held-out`` runs only them, to report once the value is chosen.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.zoo.common import design_games, game_names, load_game


def run_game(name: str, rows: list[int], ci: bool) -> list[dict]:
    from benchmarks.zoo.check import labelled_dataset
    from pcpg_dist.common.devices import set_threads
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.reporting.summary import method_used
    from pcpg_dist.stages.clustering import cluster, clustering_metrics

    set_threads(1)
    game = load_game(name)
    ds = labelled_dataset(name, ci)
    truth = np.asarray(ds.styles, np.int64)
    out = []
    for r in rows:
        cfg = ClusterConfig(k=len(game.styles), policy_rows=r)
        t0 = time.perf_counter()
        result = cluster(ds, cfg, 0)
        seconds = time.perf_counter() - t0
        m = result.metrics
        chose = method_used("bag_auto", {f"clustering/{k}": v for k, v in m.items()})
        out.append({"game": name, "steps": int((np.asarray(ds.actions) >= 0).sum()),
                    "rows": r, "chose": chose, "seconds": seconds,
                    "accuracy": float(clustering_metrics(truth, result.labels)["accuracy"]),
                    "stability": float(m.get("stability", float("nan")))})  # fmt: skip
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("games", nargs="*", help="games (default: every design game)")
    parser.add_argument("--rows", nargs="+", type=int, default=[0, 16384])
    parser.add_argument("--held-out", action="store_true", help="the held-out games instead")
    parser.add_argument("--ci", action="store_true", help="the CI-size logs")
    parser.add_argument("--json", type=Path, help="also write the rows here")
    args = parser.parse_args()
    if args.held_out:
        games = args.games or [g for g in game_names() if load_game(g).held_out]
    else:
        games = design_games(args.games, parser.error)
    rows = []
    print("| game | steps | policy_rows | default's choice | accuracy | stability | s | speed-up |")
    print("|---|---|---|---|---|---|---|---|")
    for g in games:
        found = run_game(g, args.rows, args.ci)
        rows += found
        full = next((r["seconds"] for r in found if r["rows"] == 0), float("nan"))
        for r in found:
            print(
                f"| {r['game']} | {r['steps']} | {r['rows']} | {r['chose']} | "
                f"{r['accuracy']:.3f} | {r['stability']:.2f} | {r['seconds']:.0f} | "
                f"{full / r['seconds']:.1f}x |",
                flush=True,
            )
        if args.json:
            args.json.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
