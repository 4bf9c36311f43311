"""A log streamed from Parquet and the same log as a local Minari dataset, side by side.

Writes a synthetic styled log of N trajectories (``write_styled_log``: 4 styles, 32 state
columns, ~25 steps each), exports it as a Minari dataset (``write_minari``: one folder per
episode), and runs `pcpg run` streamed (one seed, p = 1, no tracking) on each, in that order in
one process. Prints wall and per-stage seconds, clustering accuracy and PCPG / No Clustering at
p = 1 for both, and the Minari / Parquet ratios.

Run: ``uv run python benchmarks/bench_minari_stream.py [--trajectories 10000]``
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path


def run(path: str, out: Path) -> dict:
    from pcpg_dist.api.run import run_experiment
    from pcpg_dist.config import ExperimentConfig

    cfg = ExperimentConfig.model_validate(
        {
            "name": "minari-stream",
            "domain": "trajectories",
            "seeds": [0],
            "trajectories": {"path": path, "stream": "on"},
            "clustering": {"k": 4},
            "ranking": {"ps": [1.0]},
        }
    )
    t0 = time.perf_counter()
    res = run_experiment(cfg, workdir=out, track=False, show_progress=False)
    wall = time.perf_counter() - t0
    record = json.loads((res.out_dir / "summary" / "streamed.json").read_text())
    return {
        "wall": wall,
        "stages": record["stage_seconds"],
        "accuracy": record["clustering"].get("clustering/accuracy"),
        "pcpg": record["metrics"]["pcpg/accuracy/p1"],
        "nc": record["metrics"]["baseline/accuracy/p1"],
        "steps": record["steps"],
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trajectories", type=int, default=10_000)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        os.environ["MINARI_DATASETS_PATH"] = str(tmp / "minari")
        from pcpg_dist.domains.trajectories.minari_io import write_minari
        from pcpg_dist.domains.trajectories.synthetic_log import (
            styled_dataset,
            write_styled_log,
        )
        from pcpg_dist.orchestration.ray_pool import init_ray

        log = tmp / "log.parquet"
        write_styled_log(log, args.trajectories, d=32, seed=0)
        t0 = time.perf_counter()
        write_minari({"log": styled_dataset(log)}, tmp / "minari", "pcpg/styled-v0")
        export = time.perf_counter() - t0
        init_ray()
        rows = {
            "parquet": run(str(log), tmp / "a"),
            "minari": run("minari:pcpg/styled-v0", tmp / "b"),
        }
    stages = list(rows["parquet"]["stages"])
    print(
        f"{args.trajectories} trajectories, {rows['parquet']['steps']:,} steps; Minari export {export:.1f} s"
    )
    print(
        f"{'source':>8} {'wall s':>7} "
        + " ".join(f"{s:>9}" for s in stages)
        + "  accuracy  PCPG p1  NC p1"
    )
    for name, r in rows.items():
        print(
            f"{name:>8} {r['wall']:7.1f} "
            + " ".join(f"{r['stages'].get(s, 0):9.1f}" for s in stages)
            + f"  {r['accuracy']:.3f}     {r['pcpg']:.3f}   {r['nc']:.3f}"
        )
    print(f"Minari / Parquet wall: {rows['minari']['wall'] / rows['parquet']['wall']:.2f}")


if __name__ == "__main__":
    main()
