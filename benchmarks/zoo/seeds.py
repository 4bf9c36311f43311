"""The default clustering against a variant, over several seeds, side by side in one run.

One seed says little on a small log: the default's accuracy on tictactoe reads 0.58 at seed 0
and 0.47-0.48 at seeds 1-2. For each game and seed this fits ``bag_auto`` as a user gets it
(``confidence_runs`` 2, one torch thread), once with the defaults and once with ``--set``'s
keys, and prints accuracy, stability, verdict and seconds; then each game's mean accuracy, gap
to the ceiling in ``benchmarks/zoo/confidence_results.json`` and the variant's time as a
multiple of the default's. Held-out games are read only with ``--held-out``, after a choice.

    uv run python -m benchmarks.zoo.build --out zoo_data
    uv run python -m benchmarks.zoo.seeds zoo_data tictactoe highway --set latent_runs=1
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.zoo.common import ZOO, design_games, game_names, overrides


def fit(ds, k: int, seed: int, over: dict) -> dict:
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import cluster, clustering_metrics
    from pcpg_dist.stages.clustering.confidence import verdict_of

    t0 = time.perf_counter()
    result = cluster(ds, ClusterConfig(k=k, **over), seed)
    m = result.metrics
    return {
        "accuracy": clustering_metrics(np.asarray(ds.styles), result.labels)["accuracy"],
        "stability": m.get("stability", float("nan")),
        "verdict": verdict_of(m, k).verdict,
        "seconds": time.perf_counter() - t0,
    }


def main() -> None:
    from benchmarks.zoo.check import read_unit
    from pcpg_dist.common.devices import set_threads

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path, help="benchmarks.zoo.build --out")
    ap.add_argument("games", nargs="*")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--held-out", action="store_true", help="also read held-out games")
    args = ap.parse_args()
    over = overrides(args.set)
    if args.held_out:
        unknown = [g for g in args.games if g not in game_names()]
        if unknown:
            ap.error(f"{unknown[0]}: not a zoo game")
        games = args.games or game_names()
    else:
        games = design_games(args.games, ap.error)
    ceilings = {
        r["game"]: r["ceiling"]
        for r in json.loads((ZOO / "confidence_results.json").read_text())["rows"]
    }
    set_threads(1)
    for name in games:
        game, _, ds = read_unit(name, args.root / name / "labelled")
        k, runs = len(game.styles), {"default": [], "variant": []}
        for seed in args.seeds:
            for tag, keys in (("default", {}), ("variant", over)):
                r = fit(ds, k, seed, keys)
                runs[tag].append(r)
                print(
                    f"{name} seed {seed} {tag}: accuracy {r['accuracy']:.3f}, stability "
                    f"{r['stability']:.2f}, {r['verdict']}, {r['seconds']:.0f} s",
                    flush=True,
                )
        mean = {t: float(np.mean([r["accuracy"] for r in rs])) for t, rs in runs.items()}
        secs = {t: sum(r["seconds"] for r in rs) for t, rs in runs.items()}
        gap = {t: ceilings[name] - m for t, m in mean.items()}
        print(
            f"{name}: mean accuracy {mean['default']:.3f} -> {mean['variant']:.3f} (gap "
            f"{gap['default']:+.3f} -> {gap['variant']:+.3f}), time x"
            f"{secs['variant'] / secs['default']:.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
