"""Scratch: time bag_auto on the 1,600-trajectory MountainCar log by function."""
import cProfile, pstats, sys, tempfile, time
from pathlib import Path

from benchmarks.bench_log_e2e import build_log
from pcpg_dist.common.devices import set_threads

threads = int(sys.argv[1]) if len(sys.argv) > 1 else 1
n = int(sys.argv[2]) if len(sys.argv) > 2 else 1600
set_threads(threads)
tmp = Path(tempfile.mkdtemp())
log = tmp / "mc.parquet"
print(build_log(n, log), flush=True)
from pcpg_dist.config import parse_config
from pcpg_dist.domains import contract
from pcpg_dist.stages.clustering import cluster, clustering_metrics

cfg = parse_config({"name": "x", "domain": "trajectories", "seeds": [0],
    "trajectories": {"path": str(log), "score": "return", "n_actions": 3}, "clustering": {"k": 3}})
(ds,) = contract.generate(cfg, show_progress=False).values()
pr = cProfile.Profile()
t0 = time.perf_counter()
pr.enable()
res = cluster(ds, cfg.clustering, 0)
pr.disable()
print("seconds", time.perf_counter() - t0)
print({k: round(v, 3) for k, v in res.metrics.items() if "second" in k or "stab" in k or "em_" in k or "chose" in k})
print(clustering_metrics(ds, res.labels) if hasattr(ds, "styles") and ds.styles is not None else "")
pstats.Stats(pr).sort_stats("cumulative").print_stats(35)
