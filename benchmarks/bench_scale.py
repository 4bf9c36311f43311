"""How time and driver memory grow with the number of environments (random GridWorld layouts).

Runs `pcpg run` on N = 5, 20 and 80 style-distinct random layouts (``gridworld.random_layouts``,
small per-environment data), each N in a fresh process so peaks do not carry over, tracking on
(SQLite) as a user's run would have it. Prints per N: wall time, time per stage, time per
environment, peak driver RSS, peak object-store use and MLflow logging time, then the ratios the
cluster issue targets: driver peak RSS at N = 80 <= 1.5x its value at N = 5, time per environment
at N = 80 within 1.2x of N = 20.

Also the driver's own CPU seconds over the whole run, and per added environment between sizes
(the driver's serial work: planning, writing results, the summary and report, waiting on the
MLflow tasks) beside the wall of the summary and MLflow logging.

Run: ``uv run python benchmarks/bench_scale.py [--sizes 5 20 80] [--episodes 2000]``

``--log 10000 100000 1000000`` measures the other axis, one huge log (docs/scale.md): a synthetic
log of N trajectories (about 25 steps each, 32 state columns, 4 styles;
``pcpg_dist.domains.trajectories.synthetic_log``) through `pcpg run` streamed (one seed, p = 1,
no tracking), each N in a fresh process (``benchmarks/scale_log.py``), and the in-memory pipeline
on the smallest N side by side. Prints wall, per-stage seconds, the peak RSS and PSS summed over
the whole process tree (driver, raylet, GCS, every worker), spill, clustering accuracy, and the
ratios the scale-out issue targets: time per trajectory and peak memory from 10^5 to 10^6.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

CONFIG = {
    "name": "scale",
    "domain": "gridworld",
    "seed": 0,
    "seeds": [0],
    "pbtg": {"episodes": 10000, "trajectories_per_style": 160, "dataset_per_style": 40},
    "clustering": {"k": 4},
    "ranking": {"ps": [1.0, 0.5]},
    "bc": {"epochs": 300},
    "evaluation": {"rollouts_per_policy": 5, "corruption_levels": [0.0, 1.0], "figures": False},
}


def one(n: int, episodes: int | None = None) -> dict:
    """Run one size in this process and return its figures."""
    import psutil
    import ray

    from pcpg_dist.api.run import run_experiment
    from pcpg_dist.config import parse_config
    from pcpg_dist.orchestration.ray_pool import init_ray

    settings = {**CONFIG, "gridworld": {"random_layouts": {"count": n, "seed": 2024}}}
    if episodes:
        settings["pbtg"] = {**CONFIG["pbtg"], "episodes": episodes}
    cfg = parse_config(settings)
    init_ray()
    me = psutil.Process()
    peak = {"rss": me.memory_info().rss, "store": 0.0}
    stop = threading.Event()

    def sample() -> None:
        while not stop.is_set():
            peak["rss"] = max(peak["rss"], me.memory_info().rss)
            try:
                total = ray.cluster_resources().get("object_store_memory", 0.0)
                free = ray.available_resources().get("object_store_memory", total)
                peak["store"] = max(peak["store"], total - free)
            except Exception:  # noqa: BLE001 - sampling must never stop the run
                pass
            time.sleep(0.2)

    thread = threading.Thread(target=sample, daemon=True)
    thread.start()
    with tempfile.TemporaryDirectory() as tmp:
        t0, cpu0 = time.perf_counter(), time.process_time()
        result = run_experiment(
            cfg,
            workdir=Path(tmp) / "runs",
            tracking_uri=f"sqlite:///{tmp}/mlflow.db",
            show_progress=False,
        )
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    stop.set()
    thread.join()
    return {
        "n": n,
        "wall": wall,
        "driver_cpu": cpu,  # the driver process's own CPU seconds (not its Ray workers')
        "stages": result.stage_seconds,
        "rss_mb": peak["rss"] / 2**20,
        "store_mb": peak["store"] / 2**20,
        "accuracy": result.metrics.get("clustering/accuracy"),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", type=int, nargs="+", default=[5, 20, 80])
    ap.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument(
        "--episodes", type=int, default=None, help="Q-learning episodes per layout (data only)"
    )
    ap.add_argument("--log", type=int, nargs="+", default=None, help="trajectories per log")
    ap.add_argument("--log-dir", default=None, help="keep the generated logs here")
    args = ap.parse_args()
    if args.log:
        logs(args.log, args.log_dir)
        return
    if args.one is not None:
        print(json.dumps(one(args.one, args.episodes)))
        return
    rows = []
    for n in args.sizes:
        extra = ["--episodes", str(args.episodes)] if args.episodes else []
        out = subprocess.run(
            [sys.executable, __file__, "--one", str(n), *extra], capture_output=True, text=True
        )
        if out.returncode != 0:
            sys.exit(f"N={n} failed:\n{out.stderr[-3000:]}")
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    stages = list(rows[0]["stages"])
    print(
        f"{'N':>4} {'wall s':>8} {'s/env':>7} {'driver CPU s':>12} {'RSS MB':>8} {'store MB':>9} "
        + " ".join(f"{s:>9}" for s in stages)
        + "  clustering acc"
    )
    for r in rows:
        print(
            f"{r['n']:>4} {r['wall']:8.1f} {r['wall'] / r['n']:7.2f} {r['driver_cpu']:12.1f} "
            f"{r['rss_mb']:8.0f} {r['store_mb']:9.1f} "
            + " ".join(f"{r['stages'].get(s, 0):9.1f}" for s in stages)
            + f"  {r['accuracy']:.3f}"
        )
    for small, large in zip(rows, rows[1:], strict=False):
        added = large["n"] - small["n"]

        def finishing(r: dict) -> float:
            return r["stages"].get("summary", 0.0) + r["stages"].get("tracking", 0.0)

        print(
            f"N={small['n']} -> {large['n']}, per added environment: driver CPU "
            f"{1000 * (large['driver_cpu'] - small['driver_cpu']) / added:.0f} ms, summary + "
            f"MLflow wall {1000 * (finishing(large) - finishing(small)) / added:.0f} ms  "
            f"(target: driver serial work <= 50 ms per environment)"
        )
    by = {r["n"]: r for r in rows}
    if 5 in by and 80 in by:
        print(
            f"driver peak RSS N=80 / N=5 = {by[80]['rss_mb'] / by[5]['rss_mb']:.2f}  (target <= 1.5)"
        )
    if 20 in by and 80 in by:
        ratio = (by[80]["wall"] / 80) / (by[20]["wall"] / 20)
        print(f"time per environment N=80 / N=20 = {ratio:.2f}  (target <= 1.2)")


def _log_child(log: Path, out: str, stream: str) -> dict:
    child = Path(__file__).with_name("scale_log.py")
    done = subprocess.run(
        [sys.executable, str(child), str(log), out, "0", stream], capture_output=True, text=True
    )
    if done.returncode != 0:
        sys.exit(f"{log} ({stream}) failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def logs(sizes: list[int], keep: str | None) -> None:
    from pcpg_dist.domains.trajectories.synthetic_log import write_styled_log

    folder = Path(keep or tempfile.mkdtemp(prefix="pcpg-scale-log-"))
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for n in sorted(sizes):
        log = folder / f"log-{n}.parquet"
        if not log.exists():
            write_styled_log(log, n, d=32, seed=0)
        # a fresh run folder each time: the in-memory pipeline would resume from its cache
        if n == min(sizes):
            rows.append({"n": n, **_log_child(log, tempfile.mkdtemp(dir=folder), "off")})
        rows.append({"n": n, **_log_child(log, tempfile.mkdtemp(dir=folder), "on")})
    print(
        f"{'N':>9} {'how':>9} {'wall s':>7} {'ms/traj':>8} {'RSS GB':>7} {'PSS GB':>7} "
        f"{'spill GB':>8} {'acc':>6} {'PCPG':>6} {'NC':>6}  stages (s)"
    )
    for r in rows:
        how = "streamed" if r["stream"] == "on" else "in-memory"
        print(
            f"{r['n']:>9} {how:>9} {r['wall_s']:7.1f} {1000 * r['wall_s'] / r['n']:8.3f} "
            f"{r['peak_tree_rss_gb']:7.2f} {r['peak_tree_pss_gb']:7.2f} {r.get('spilled_gb', 0):8.2f} "
            f"{r['clustering_accuracy']:6.3f} {r['pcpg_p1']:6.3f} {r['nc_p1']:6.3f}  {r['stage_s']}"
        )
    by = {r["n"]: r for r in rows if r["stream"] == "on"}
    if 100_000 in by and 1_000_000 in by:
        a, b = by[100_000], by[1_000_000]
        per = (b["wall_s"] / 1e6) / (a["wall_s"] / 1e5)
        print(f"time per trajectory 10^6 / 10^5 = {per:.2f}  (target <= 1.2)")
        print(
            f"peak tree PSS 10^6 / 10^5 = {b['peak_tree_pss_gb'] / a['peak_tree_pss_gb']:.2f}, "
            f"RSS sum {b['peak_tree_rss_gb'] / a['peak_tree_rss_gb']:.2f}  (target <= 1.5)"
        )
    low = min(by)
    print(
        "clustering accuracy by size: "
        + ", ".join(f"{n}: {r['clustering_accuracy']:.4f}" for n, r in sorted(by.items()))
        + f" (as good as at {low}: {all(r['clustering_accuracy'] >= by[low]['clustering_accuracy'] - 0.005 for r in by.values())})"
    )


if __name__ == "__main__":
    main()
