"""A user's big log: load + validate a 100,000-trajectory Parquet step table, then cluster it.

Issue target (open domains): the log loads and validates in <= 10 s, and clusters within 24 GB.
The log is the FrozenLake 8x8 example game (4 styles, one-hot 64-d states,
``pcpg_dist.domains.trajectories.example_logs``): a pool of played trajectories is tiled with new
ids up to N, so the size is real and generation stays cheap. Each measurement runs in its own
process and reports that process's peak RSS.

Run: ``uv run python benchmarks/bench_trajectories.py [--n 100000]``
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CHILD = r"""
import json, resource, sys, time
from pcpg_dist.common.devices import set_threads
set_threads(1)
from pcpg_dist.domains.trajectories.table import datasets_from_table
from pcpg_dist.domains.trajectories.table_files import read_step_table
t0 = time.perf_counter()
(ds,) = datasets_from_table(read_step_table(sys.argv[1])).values()
load = time.perf_counter() - t0
out = {"load_seconds": load, "trajectories": ds.n_trajectories, "rows": ds.n_rows}
if sys.argv[2] != "none":
    from pcpg_dist.stages.clustering import cluster, clustering_metrics
    from pcpg_dist.config import ClusterConfig
    cfg = ClusterConfig(k=4, method=sys.argv[2], pretrain_epochs=1, dec_epochs=1, batch_size=1024)
    t0 = time.perf_counter()
    res = cluster(ds, cfg, 0)
    out.update(cluster_seconds=time.perf_counter() - t0,
               accuracy=clustering_metrics(ds.styles, res.labels)["accuracy"])
out["peak_rss_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
print(json.dumps(out))
"""


def make_log(path: Path, n: int, seed: int = 0) -> float:
    from pcpg_dist.domains.trajectories.example_logs import frozenlake_logs

    pool = frozenlake_logs(per_style=250, seed=seed)  # 1000 played trajectories
    reps = int(np.ceil(n / pool.trajectory.nunique()))
    size = pool.trajectory.nunique()
    parts = [pool.assign(trajectory=pool.trajectory + r * size) for r in range(reps)]
    import pandas as pd

    table = pd.concat(parts, ignore_index=True)
    table = table[table.trajectory < n]
    table.to_parquet(path, index=False)
    return path.stat().st_size / 2**20


def run_child(path: Path, method: str) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(path), method], capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=100_000, help="trajectories in the log")
    ap.add_argument(
        "--methods",
        default="none,visits_kmeans,lstm_dec",
        help="comma-separated: none (load only) and clustering methods (lstm_* run 1+1 epochs)",
    )
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "big.parquet"
        t0 = time.perf_counter()
        mb = make_log(path, args.n)
        print(
            f"log: {args.n} trajectories, {mb:.0f} MiB Parquet, made in {time.perf_counter() - t0:.0f} s"
        )
        print(f"{'step':<26} {'load+validate':>14} {'cluster':>9} {'accuracy':>9} {'peak RSS':>9}")
        for method in args.methods.split(","):
            r = run_child(path, method)
            cl = f"{r['cluster_seconds']:8.1f}s" if "cluster_seconds" in r else f"{'-':>9}"
            acc = f"{r['accuracy']:9.3f}" if "accuracy" in r else f"{'-':>9}"
            name = "load only" if method == "none" else f"load + {method}"
            print(f"{name:<26} {r['load_seconds']:13.1f}s {cl} {acc} {r['peak_rss_gb']:8.2f}G")
        print(
            f"targets: load+validate <= 10 s; clustering within 24 GB "
            f"(this process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20:.2f} G)"
        )


if __name__ == "__main__":
    main()
