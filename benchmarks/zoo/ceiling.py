"""Recompute every zoo game's ceiling (the supervised panel of ``clustering/ceiling``) and carry it
into the results of :mod:`.evaluate` and :mod:`.confidence`: their ceilings, gaps and the
confidence's summary. The clusterings are not rerun; use this when only the panel changed.

    uv run python -m benchmarks.zoo.ceiling benchmarks/zoo/evaluate_results.json \
        benchmarks/zoo/confidence_results.json

Each game is built as :mod:`.evaluate` builds it (full size, seed 0), so the trajectories are the
ones those results were measured on.
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from benchmarks.zoo.confidence import summary
from pcpg_dist.stages.clustering.ceiling import gap_to_ceiling


def panel_of(name: str) -> tuple[str, dict, float]:
    from benchmarks.zoo.check import labelled_dataset
    from pcpg_dist.common.devices import set_threads
    from pcpg_dist.stages.clustering.ceiling import ceiling_panel

    set_threads(1)  # one worker process per core
    ds = labelled_dataset(name, False)
    t0 = time.perf_counter()
    return name, ceiling_panel(ds, seed=0), time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("evaluated", type=Path, help="benchmarks.zoo.evaluate --out")
    ap.add_argument("confidence", type=Path, help="benchmarks.zoo.confidence --out")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    evaluated = json.loads(args.evaluated.read_text())
    confidence = json.loads(args.confidence.read_text())
    games = [r["game"] for r in evaluated]
    with ProcessPoolExecutor(args.workers) as pool:
        panels = {name: (panel, s) for name, panel, s in pool.map(panel_of, games)}
    for r in evaluated:
        panel, seconds = panels[r["game"]]
        print(f"{r['game']}: ceiling {r['ceiling']:.3f} -> {max(panel.values()):.3f} {panel}")
        r.update(ceiling=max(panel.values()), panel=panel, ceiling_seconds=seconds)
    for r in confidence["rows"]:
        r["ceiling"] = max(panels[r["game"]][0].values())
        r["gap"] = gap_to_ceiling(r["ceiling"], r["accuracy"])
    confidence["summary"] = summary(confidence["rows"])
    args.evaluated.write_text(json.dumps(evaluated, indent=1))
    args.confidence.write_text(json.dumps(confidence, indent=1))
    print(json.dumps(confidence["summary"], indent=1))


if __name__ == "__main__":
    main()
