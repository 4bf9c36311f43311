"""Step A benchmark: quality and speed of every clusterer on every environment of a dataset.

    uv run pcpg generate experiments/gridworld_paper.yaml --out data/paper
    uv run python benchmarks/bench_clustering.py --data data/paper --threads 2 --seeds 0 1

Prints one table per environment (method, ARI, NMI, Hungarian accuracy, silhouette, wall and CPU
seconds of the fit) and a summary of the targets (LSTM: accuracy >= 0.95, ARI >= 0.9, fit <= 60 s).
CPU seconds are printed beside wall seconds because the development machine is shared: with one
thread CPU time is what the fit would take alone; with two, wall time alone is the honest figure
only on an idle machine. ``--set key=value`` overrides ClusterConfig fields (JSON values).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

from pcpg_dist.clustering import ClusterConfig, cluster, clustering_metrics
from pcpg_dist.dataset import load_datasets
from pcpg_dist.parallel import set_threads

METHODS = ("lstm_dec", "lstm_kmeans", "summary_kmeans")


def parse_overrides(items: list[str]) -> dict:
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def fit_once(ds, cfg: ClusterConfig, seed: int) -> dict[str, float]:
    cpu0, wall0 = time.process_time(), time.perf_counter()
    res = cluster(ds, cfg, seed=seed)
    row = {"wall_s": time.perf_counter() - wall0, "cpu_s": time.process_time() - cpu0}
    row.update(clustering_metrics(ds.styles, res.labels))
    row["silhouette"] = res.metrics.get("silhouette", float("nan"))
    return row


def mean_std(values: list[float]) -> str:
    if len(values) == 1:
        return f"{values[0]:.3f}"
    return f"{statistics.mean(values):.3f}±{statistics.stdev(values):.3f}"


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--data", type=Path, default=Path("data/paper"))
    ap.add_argument("--envs", nargs="*", help="environments to run (default: all)")
    ap.add_argument("--methods", nargs="*", default=list(METHODS), choices=METHODS)
    ap.add_argument("--seeds", nargs="*", type=int, default=[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--set", nargs="*", default=[], metavar="KEY=VALUE", help="ClusterConfig overrides"
    )
    ap.add_argument("--json", type=Path, help="also write every row to this JSON file")
    args = ap.parse_args()

    if not (args.data / "manifest.json").is_file():
        raise SystemExit(
            f"{args.data}: no dataset; run `uv run pcpg generate "
            f"experiments/gridworld_paper.yaml --out {args.data}` first"
        )
    set_threads(args.threads)
    data = load_datasets(args.data)
    overrides = parse_overrides(args.set)
    print(
        f"threads={args.threads} cpus={os.cpu_count()} load={os.getloadavg()[0]:.1f} "
        f"seeds={args.seeds} overrides={overrides}"
    )
    rows, targets = [], []
    for env in args.envs or sorted(data):
        ds = data[env]
        print(
            f"\n{env}: {ds.n_trajectories} trajectories, lengths {ds.lengths.min()}-"
            f"{ds.lengths.max()} (mean {ds.lengths.mean():.1f}), {ds.n_rows} states"
        )
        print(
            f"{'method':<15}{'ARI':>14}{'NMI':>14}{'accuracy':>14}{'silhouette':>14}"
            f"{'wall s':>10}{'cpu s':>10}"
        )
        for method in args.methods:
            cfg = ClusterConfig(method=method, **overrides)
            runs = [fit_once(ds, cfg, seed) for seed in args.seeds]
            for seed, r in zip(args.seeds, runs, strict=True):
                rows.append({"env": env, "method": method, "seed": seed, **r})
            col = {key: [r[key] for r in runs] for key in runs[0]}
            print(
                f"{method:<15}{mean_std(col['ari']):>14}{mean_std(col['nmi']):>14}"
                f"{mean_std(col['accuracy']):>14}{mean_std(col['silhouette']):>14}"
                f"{statistics.mean(col['wall_s']):>10.1f}{statistics.mean(col['cpu_s']):>10.1f}",
                flush=True,
            )
            if method == "lstm_dec":
                targets.append((env, min(col["accuracy"]), min(col["ari"]), max(col["wall_s"])))
    if targets:
        print("\ntargets (lstm_dec, worst seed): accuracy >= 0.95, ARI >= 0.9, fit <= 60 s")
        for env, acc, ari, wall in targets:
            ok = "ok" if acc >= 0.95 and ari >= 0.9 and wall <= 60 else "MISSED"
            print(f"  {env}: accuracy {acc:.3f}  ARI {ari:.3f}  wall {wall:.1f} s  {ok}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
