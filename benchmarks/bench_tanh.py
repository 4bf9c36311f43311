"""The clusterers' tanh, side by side: torch.tanh (until the eighteenth session) against
:func:`pcpg_dist.stages.clustering.policy_network.tanh` (2 sigmoid(2x) - 1, tanh's own backward),
one torch thread, in one run: a hidden layer's forward + backward on the shapes policy_mix fits
(4,096 and 32,768 rows, 64 units), then one policy_mix fit of a log with each.

    uv run python -m benchmarks.bench_tanh [--repeats 50] [--game mountaincar] [--no-fit]

Prints milliseconds (seconds for the fit) and the ratio old / new. The fit uses the zoo game's
full-size log (``benchmarks.zoo``), ``policy_mix`` with the default latent start, k = its styles,
no refits; it prints both fits' clustering accuracy too (the two tanh differ by float rounding,
so the labels may differ where a trajectory is on the edge).
"""

from __future__ import annotations

import argparse
import importlib
import time

import torch

policy_network = importlib.import_module("pcpg_dist.stages.clustering.policy_network")
latent_start = importlib.import_module("pcpg_dist.stages.clustering.latent_start")


def layer_ms(act, rows: int, repeats: int, gen: torch.Generator) -> float:
    """Milliseconds per forward + backward of ``act`` after a 64 x 64 linear layer."""
    x = torch.randn(rows, 64, generator=gen)
    w = (0.2 * torch.randn(64, 64, generator=gen)).requires_grad_()
    for step in range(repeats + 3):  # 3 warm-up calls
        if step == 3:
            start = time.perf_counter()
        act(x @ w).sum().backward()
    return (time.perf_counter() - start) / repeats * 1000


def fit_seconds(ds, k: int, use_torch: bool) -> tuple[float, float]:
    """(seconds, accuracy) of one policy_mix fit of ``ds`` with torch.tanh or the new tanh."""
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import cluster, clustering_metrics

    cfg = ClusterConfig(k=k, method="policy_mix", confidence_runs=0)
    fast = policy_network.tanh
    chosen = torch.tanh if use_torch else fast
    policy_network.tanh = latent_start.tanh = chosen  # Tanh layers call the module's name
    try:
        start = time.perf_counter()
        labels = cluster(ds, cfg, 0).labels
        seconds = time.perf_counter() - start
    finally:
        policy_network.tanh = latent_start.tanh = fast
    return seconds, clustering_metrics(ds.styles, labels)["accuracy"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--game", default="mountaincar")
    parser.add_argument("--no-fit", action="store_true", help="the layer timings only")
    args = parser.parse_args()
    torch.set_num_threads(1)
    gen = torch.Generator().manual_seed(0)
    print(f"{'rows':>7} {'torch.tanh ms':>14} {'new ms':>8} {'old/new':>8}")
    for rows in (4096, 32768):
        old, new = (
            layer_ms(act, rows, args.repeats, gen) for act in (torch.tanh, policy_network.tanh)
        )
        print(f"{rows:>7} {old:>14.2f} {new:>8.2f} {old / new:>8.2f}")
    if args.no_fit:
        return
    from benchmarks.zoo.check import labelled_dataset
    from benchmarks.zoo.common import load_game

    ds, k = labelled_dataset(args.game, False), len(load_game(args.game).styles)  # built once
    (old, old_acc), (new, new_acc) = (fit_seconds(ds, k, t) for t in (True, False))
    print(
        f"policy_mix on {args.game}: torch.tanh {old:.1f} s (accuracy {old_acc:.3f}), new "
        f"{new:.1f} s ({new_acc:.3f}), old/new {old / new:.2f}"
    )


if __name__ == "__main__":
    main()
