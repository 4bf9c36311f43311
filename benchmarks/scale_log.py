"""One huge log through `pcpg run` (streamed), measured: wall, per-stage seconds, the peak RSS
and PSS summed over the whole process tree (the driver, Ray's raylet, GCS and every worker),
object-store spill, clustering accuracy. Called by ``bench_scale.py log``; each size runs in a
fresh process (``python benchmarks/scale_log.py LOG OUT``)."""

from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path

LAST: list = []


def tree_memory(pid: int) -> tuple[float, float]:
    """(sum of RSS, sum of PSS) in GB over a process and all its descendants."""
    import psutil

    rss = pss = 0
    global LAST
    LAST = []
    try:
        root = psutil.Process(pid)
        procs = [root, *root.children(recursive=True)]
    except psutil.NoSuchProcess:
        return 0.0, 0.0
    for p in procs:
        try:
            info = p.memory_full_info()
            rss, pss = rss + info.rss, pss + info.pss
            LAST.append((info.rss / 2**20, info.pss / 2**20, " ".join(p.cmdline()[:3])[:80]))
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            pass
    return rss / 2**30, pss / 2**30


def spilled_gb() -> float:
    """Bytes in the object store's spill folder now (polled by the watcher for the peak)."""
    import contextlib
    import glob
    import os

    import ray

    session = ray._private.worker.global_worker.node.get_session_dir_path()
    total = 0
    for folder in glob.glob(os.path.join(session, "ray_spilled_objects*")):
        for root, _, files in os.walk(folder):
            for f in files:
                with contextlib.suppress(OSError):  # freed while we looked
                    total += os.path.getsize(os.path.join(root, f))
    return total / 2**30


def main(log: str, out: str, seeds: str = "0", stream: str = "on") -> None:
    import os

    from pcpg_dist.api.run import run_experiment
    from pcpg_dist.config import ExperimentConfig
    from pcpg_dist.orchestration.ray_pool import init_ray

    peak = {"rss": 0.0, "pss": 0.0, "spill": 0.0}
    stop = threading.Event()

    def watch() -> None:
        while not stop.is_set():
            rss, pss = tree_memory(os.getpid())
            peak["spill"] = max(peak["spill"], spilled_gb())
            if rss > peak["rss"]:
                peak["procs"] = sorted((p for p in LAST if p[0] >= 50), reverse=True)
                peak["at"] = round(time.perf_counter() - t0)
            peak["rss"], peak["pss"] = max(peak["rss"], rss), max(peak["pss"], pss)
            time.sleep(1.0)

    t0 = time.perf_counter()
    init_ray()
    threading.Thread(target=watch, daemon=True).start()
    cfg = ExperimentConfig.model_validate(
        {
            "name": "scale-log",
            "domain": "trajectories",
            "seeds": [int(s) for s in seeds.split(",")],
            "trajectories": {"path": log, "stream": stream},
            "clustering": {"k": 4},
            "ranking": {"ps": [1.0]},
        }
    )
    res = run_experiment(cfg, workdir=Path(out), track=False, show_progress=False)
    wall = time.perf_counter() - t0
    stop.set()
    if stream == "off":  # the in-memory pipeline, for the side-by-side
        stop.set()
        print(
            json.dumps(
                {
                    "stream": "off",
                    "wall_s": round(wall, 1),
                    "stage_s": {k: round(v, 1) for k, v in res.stage_seconds.items()},
                    "peak_tree_rss_gb": round(peak["rss"], 2),
                    "peak_tree_pss_gb": round(peak["pss"], 2),
                    "clustering_accuracy": next(iter(res.clustering.values())).get(
                        "clustering/accuracy"
                    ),
                    "pcpg_p1": res.metrics.get("pcpg/accuracy/p1"),
                    "nc_p1": res.metrics.get("baseline/accuracy/p1"),
                }
            )
        )
        return
    spill = peak["spill"]
    record = json.loads((res.out_dir / "summary" / "streamed.json").read_text())
    print(
        json.dumps(
            {
                "stream": "on",
                "trajectories": record["n_trajectories"],
                "steps": record["steps"],
                "wall_s": round(wall, 1),
                "stage_s": {k: round(v, 1) for k, v in record["stage_seconds"].items()},
                "peak_tree_rss_gb": round(peak["rss"], 2),
                "peak_tree_pss_gb": round(peak["pss"], 2),
                "spilled_gb": round(spill, 2),
                "clustering_accuracy": record["clustering"].get("clustering/accuracy"),
                "pcpg_p1": record["metrics"].get("pcpg/accuracy/p1"),
                "nc_p1": record["metrics"].get("baseline/accuracy/p1"),
                "bc_epochs": record["bc_epochs"],
                "peak_at_s": peak.get("at"),
                "peak_processes_mb": [[round(a), round(b), c] for a, b, c in peak.get("procs", [])],
            }
        )
    )


if __name__ == "__main__":
    main(*sys.argv[1:])
