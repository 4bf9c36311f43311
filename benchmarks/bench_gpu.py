"""The neural stages on a GPU (``clustering.device`` / ``bc.device`` cuda) beside the CPU, in one run.

    uv run python benchmarks/bench_gpu.py [--threads 1] [--parts lstm policy_mix bc] [--cache DIR]

- ``lstm``: the paper's clusterer (``lstm_dec``) on E1-E5 (PBTG seed 0, 1000 trajectories per
  style, as bench_clustering.py), fitted on the CPU and twice on cuda: accuracy, the ARI between
  the CPU's and the GPU's labels, whether the two GPU fits agree, seconds and the CPU / GPU ratio.
- ``policy_mix``: MiniDungeons' clusterer on its paper unit (780 trajectories, k = 6, data seed 0).
- ``bc``: Step C's 500 models of the GridWorld protocol on the same data (5 envs x 4 seeds x
  5 p x (4 styles + No Clustering), 2000 full-batch epochs): numba on the CPU against the torch
  engine on cuda, one call each, and their mean accuracy on every held-out step.

GPU times are taken after a warm-up fit (CUDA context, cuDNN plans) and with the device
synchronised. Without a GPU the CPU side runs alone and the script says so. The last lines are
a table of every figure, also written as JSON with ``--json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_clustering import datasets, minidungeons_units  # noqa: E402

from pcpg_dist.common.devices import set_threads  # noqa: E402
from pcpg_dist.config.stages import BCConfig  # noqa: E402
from pcpg_dist.domains.defaults import split_trajectories  # noqa: E402
from pcpg_dist.stages.bc import train_cells  # noqa: E402
from pcpg_dist.stages.clustering import ClusterConfig, cluster, clustering_metrics  # noqa: E402
from pcpg_dist.stages.ranking import RankConfig, plan_cells  # noqa: E402


def timed(fn, cuda: bool):
    if cuda:
        torch.cuda.synchronize()
    t0 = time.perf_counter()
    out = fn()
    if cuda:
        torch.cuda.synchronize()
    return out, time.perf_counter() - t0


def bench_clusterer(
    name: str, ds, clustered, cfg: ClusterConfig, gpu: bool, rows: list[dict]
) -> None:
    """CPU fit, then two cuda fits; one row of figures."""
    from sklearn.metrics import adjusted_rand_score

    cpu, cpu_s = timed(lambda: cluster(clustered, cfg, seed=0), False)
    row = {
        "part": cfg.method,
        "unit": name,
        "cpu_s": cpu_s,
        "cpu_acc": clustering_metrics(ds.styles, cpu.labels)["accuracy"],
    }
    if gpu:
        on_gpu = cfg.model_copy(update={"device": "cuda"})
        a, a_s = timed(lambda: cluster(clustered, on_gpu, seed=0), True)
        b, _ = timed(lambda: cluster(clustered, on_gpu, seed=0), True)
        row.update(
            gpu_s=a_s,
            gpu_acc=clustering_metrics(ds.styles, a.labels)["accuracy"],
            ari_cpu_gpu=adjusted_rand_score(cpu.labels, a.labels),
            gpu_repeat_same=float(np.array_equal(a.labels, b.labels)),
        )
    rows.append(row)
    print(_fmt(row), flush=True)


def bench_bc(data: dict, gpu: bool, rows: list[dict]) -> None:
    rank, seeds, cfg = RankConfig(), [0, 1, 2, 3], BCConfig(epochs=2000)
    cells, tests = [], {}
    for env, ds in data.items():
        tr, te = split_trajectories(ds.n_trajectories, rank.test_fraction, rank.split_seed)
        cells += plan_cells(ds, ds.styles, tr, rank, seeds, prefix=f"{env}/")
        test = ds.subset(te)
        r = test.step_rows
        tests[env] = (test.states[r], test.valid_mask[r], test.actions[r])

    def accuracy(model) -> float:
        per_cell = []
        for i, c in enumerate(cells):
            s, v, a = tests[c.key.split("/")[0]]
            per_cell.append((model.predict(s, v, i) == a).mean())
        return float(np.mean(per_cell))

    train_cells(cells[:1], BCConfig(epochs=1))  # numba compiles once (cached on disk after)
    cpu, cpu_s = timed(lambda: train_cells(cells, cfg), False)
    row = {"part": "bc", "unit": f"{len(cells)} models", "cpu_s": cpu_s, "cpu_acc": accuracy(cpu)}
    if gpu:
        on_gpu = cfg.model_copy(update={"device": "cuda"})
        train_cells(cells[:5], on_gpu.model_copy(update={"epochs": 5}))  # warm-up
        g, g_s = timed(lambda: train_cells(cells, on_gpu), True)
        row.update(gpu_s=g_s, gpu_acc=accuracy(g))
    rows.append(row)
    print(_fmt(row), flush=True)


def _fmt(row: dict) -> str:
    parts = [
        f"{row['part']:10s} {row['unit']:12s} cpu {row['cpu_acc']:.3f} in {row['cpu_s']:6.1f} s"
    ]
    if "gpu_s" in row:
        parts.append(
            f"cuda {row['gpu_acc']:.3f} in {row['gpu_s']:6.1f} s  cpu/cuda {row['cpu_s'] / row['gpu_s']:5.2f}x"
        )
    if "ari_cpu_gpu" in row:
        parts.append(
            f"ARI(cpu, cuda) {row['ari_cpu_gpu']:.3f}  cuda twice same labels "
            f"{'yes' if row['gpu_repeat_same'] else 'no'}"
        )
    return "  ".join(parts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--threads",
        type=int,
        default=1,
        help="CPU threads (pcpg's tasks use runner.cpus_per_task: 1)",
    )
    ap.add_argument(
        "--parts",
        nargs="+",
        default=["lstm", "policy_mix", "bc"],
        choices=["lstm", "policy_mix", "bc"],
    )
    ap.add_argument("--cache", default=".bench_cache")
    ap.add_argument("--json", default=None, help="also write the rows here")
    args = ap.parse_args()
    set_threads(args.threads)
    gpu = torch.cuda.is_available()
    print(
        f"torch {torch.__version__}; GPU: {torch.cuda.get_device_name(0) if gpu else 'none (CPU side only)'}; "
        f"CPU threads {args.threads}",
        flush=True,
    )
    data = {name: ds for _, name, ds, _ in datasets(Path(args.cache), 0, 0, groups=("paper",))}
    if gpu:  # CUDA context and cuDNN plans, outside every timed fit
        first = next(iter(data.values()))
        cluster(
            first.subset(np.arange(64)),
            ClusterConfig(k=4, method="lstm_dec", device="cuda", pretrain_epochs=1, dec_epochs=1),
            seed=0,
        )
    rows: list[dict] = []
    if "lstm" in args.parts:
        for name, ds in data.items():
            bench_clusterer(name, ds, ds, ClusterConfig(k=4, method="lstm_dec"), gpu, rows)
    if "policy_mix" in args.parts:
        for _, name, raw, clustered in minidungeons_units([0]):
            bench_clusterer(
                f"MD {name}", raw, clustered, ClusterConfig(k=6, method="policy_mix"), gpu, rows
            )
    if "bc" in args.parts:
        bench_bc(data, gpu, rows)
    print("\npart        unit          cpu acc   cuda acc   cpu s   cuda s   cpu/cuda")
    for r in rows:
        g = "gpu_s" in r
        print(
            f"{r['part']:10s}  {r['unit']:12s}  {r['cpu_acc']:7.3f}  {r.get('gpu_acc', float('nan')):8.3f}  "
            f"{r['cpu_s']:6.1f}  {r.get('gpu_s', float('nan')):7.1f}  "
            f"{(r['cpu_s'] / r['gpu_s']) if g else float('nan'):7.2f}x"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
