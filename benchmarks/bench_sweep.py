"""A 12-point sweep over ``bc.*`` against one point of the same config, side by side in one run.

Issue target: the whole 12-point sweep in <= 1.5x the time of one point (the sweep shares the data
and the clustering, and its BC and evaluation tasks interleave on Ray). Prints wall time, units
computed per stage (the rest were cache hits) and the ratios, for:

- one point: `pcpg run` of the config from an empty cache;
- the sweep: `pcpg sweep` of 12 points from an empty cache;
- one by one: 12 x the one-point time (what 12 separate `pcpg run`s with separate caches cost).

Run: ``uv run python benchmarks/bench_sweep.py [CONFIG]`` (default experiments/quick.yaml).
Tracking is on (a SQLite store in a temporary folder), as a user's sweep would have it.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from pcpg_dist.api.run import run_experiment
from pcpg_dist.api.sweep import run_sweep
from pcpg_dist.config.overrides import load_config_with
from pcpg_dist.orchestration.ray_pool import init_ray

ROOT = Path(__file__).resolve().parent.parent
AXES = ["bc.hidden_size=8,16,32", "bc.lr=0.001,0.003,0.01,0.03"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("config", nargs="?", default=str(ROOT / "experiments" / "quick.yaml"))
    ap.add_argument("--no-tracking", action="store_true")
    args = ap.parse_args()
    init_ray()
    track = not args.no_tracking
    with tempfile.TemporaryDirectory() as tmp:
        uri = f"sqlite:///{tmp}/mlflow.db"
        cfg = load_config_with(args.config, ["bc.hidden_size=8", "bc.lr=0.001"])
        t0 = time.perf_counter()
        one = run_experiment(
            cfg, workdir=Path(tmp) / "one", tracking_uri=uri, track=track, show_progress=False
        )
        t_one = time.perf_counter() - t0
        t0 = time.perf_counter()
        sweep = run_sweep(
            args.config,
            AXES,
            workdir=Path(tmp) / "sweep",
            tracking_uri=uri,
            track=track,
            show_progress=False,
        )
        t_sweep = time.perf_counter() - t0
        stages = sweep_stage_seconds(sweep)
    n = len(sweep.rows)
    print(
        f"config {Path(args.config).name}; sweep axes {' x '.join(AXES)} = {n} points; tracking {track}"
    )
    print(f"{'':<14}{'wall s':>9}{'data':>6}{'cluster':>9}{'train':>7}{'eval':>6}")
    c1, cs = one.computed, sweep.computed
    print(
        f"{'one point':<14}{t_one:9.1f}{c1['data']:6d}{c1['clustering']:9d}{c1['train_groups']:7d}"
        f"{c1['evaluations']:6d}"
    )
    print(
        f"{'sweep':<14}{t_sweep:9.1f}{cs['data']:6d}{cs['clustering']:9d}{cs['train_groups']:7d}"
        f"{cs['evaluations']:6d}"
    )
    print(
        f"{'one by one':<14}{n * t_one:9.1f}{n * c1['data']:6d}{n * c1['clustering']:9d}"
        f"{n * c1['train_groups']:7d}{n * c1['evaluations']:6d}   (12 x one point)"
    )
    hits = {
        s: n * c1[k] - cs[k]
        for s, k in (
            ("data", "data"),
            ("cluster", "clustering"),
            ("train", "train_groups"),
            ("eval", "evaluations"),
        )
    }
    print(
        "units shared by content key (cache hits vs one by one): "
        + ", ".join(f"{s} {h}" for s, h in hits.items())
    )
    print(
        f"sweep / one point = {t_sweep / t_one:.2f}  (target <= 1.5); one by one / sweep = "
        f"{n * t_one / t_sweep:.1f}x"
    )
    print(
        "one point stage seconds: "
        + ", ".join(f"{k} {v:.1f}" for k, v in one.stage_seconds.items())
    )
    print("sweep stage seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in stages.items()))


def sweep_stage_seconds(sweep) -> dict[str, float]:
    import json

    first = next(iter(sorted((sweep.out_dir / "points").iterdir())))
    return json.loads((first / "summary" / "run.json").read_text())["stage_seconds"]


if __name__ == "__main__":
    main()
