"""Speed of Step C on the GridWorld paper protocol, against a plain per-model PyTorch loop.

    uv run python benchmarks/bench_bc.py [--data data/paper] [--threads 2] [--sample 10]

Trains all 500 BC models of the protocol (5 envs x 4 seeds x 5 p x (4 styles + No Clustering))
for 2000 full-batch epochs in one call, then trains a sample of the same cells one after another
with a plain PyTorch loop (nn.Sequential, Adam, shuffled minibatches of 64 over the raw steps)
and prints the per-model speed ratio and both test accuracies on the same test subsets.
Wall and CPU seconds are both printed: on a shared machine the wall clock mostly measures the
neighbours.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from pcpg_dist.common.devices import set_threads
from pcpg_dist.config.stages import BCConfig
from pcpg_dist.dataset import load_datasets
from pcpg_dist.domains.defaults import performance, split_trajectories
from pcpg_dist.stages.bc import train_cells
from pcpg_dist.stages.ranking import RankConfig, plan_cells, threshold, threshold_all


def plain_loop(states, valid, actions, mean, std, sizes, epochs, batch, lr, seed, activation):
    """What a user would write: one model, shuffled minibatches, autograd, torch.optim.Adam."""
    torch.manual_seed(seed)
    layers: list[torch.nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        layers.append(torch.nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(torch.nn.Tanh() if activation == "tanh" else torch.nn.ReLU())
    model = torch.nn.Sequential(*layers)
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    x = torch.tensor((states - mean) / std, dtype=torch.float32)
    v = torch.tensor(valid)
    y = torch.tensor(actions)
    for _ in range(epochs):
        perm = torch.randperm(len(y))
        for j in range(0, len(y), batch):
            b = perm[j : j + batch]
            logits = model(x[b]).masked_fill(~v[b], float("-inf"))
            loss = torch.nn.functional.cross_entropy(logits, y[b])
            opt.zero_grad()
            loss.backward()
            opt.step()
    return model


def test_rows(ds, subset):
    test = ds.subset(subset)
    r = test.step_rows
    return test.states[r], test.valid_mask[r], test.actions[r]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/paper")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--sample", type=int, default=10, help="cells trained by the plain loop")
    ap.add_argument("--plain-epochs", type=int, default=20)
    ap.add_argument("--plain-lr", type=float, default=0.01)
    ap.add_argument("--epochs", type=int, default=2000)
    args = ap.parse_args()
    if not Path(args.data).is_dir():
        raise SystemExit(
            f"{args.data}: run `uv run pcpg generate experiments/gridworld_paper.yaml "
            f"--out {args.data}` first"
        )
    rank, seeds = RankConfig(), [0, 1, 2, 3]
    cfg = BCConfig(epochs=args.epochs)
    datasets = load_datasets(Path(args.data))
    t0 = time.perf_counter()
    cells, splits = [], {}
    for env, ds in sorted(datasets.items()):
        tr, te = split_trajectories(ds.n_trajectories, rank.test_fraction, rank.split_seed)
        splits[env] = (tr, te)
        cells += plan_cells(ds, ds.styles, tr, rank, seeds, prefix=f"{env}/")
    plan_s = time.perf_counter() - t0
    raw = sum(c.weights.sum() for c in cells)
    rows = sum(c.n_rows for c in cells)
    print(
        f"{len(cells)} models, {raw:.0f} raw steps -> {rows} distinct rows "
        f"({raw / rows:.0f}x fewer); planning {plan_s:.1f} s"
    )
    # the plain loop runs first (before numba starts its threads) with one thread: a per-model
    # loop of a 5-unit net gains nothing from threads, and 2 torch threads on a busy 2-core
    # machine were measured ~100x slower
    set_threads(1)
    rng = np.random.default_rng(0)
    sample = sorted(rng.choice(len(cells), size=min(args.sample, len(cells)), replace=False))
    plain_s, plain_cpu, acc_b, acc_p, tests = [], [], [], [], []
    for i in sample:
        cell = cells[i]
        env = cell.key.split("/")[0]
        ds = datasets[env]
        tr, te = splits[env]
        spec = cell.spec
        raw_cell = next(
            c
            for c in plan_cells(
                ds, ds.styles, tr, RankConfig(ps=(spec.p,)), [spec.seed], dedupe=False
            )
            if c.spec.kind == spec.kind and c.spec.k == spec.k
        )
        scores = performance(ds, rank.beta)
        subset = (
            threshold(ds.styles, te, scores, ds.trajectory_ids, [spec.p])[(spec.k, spec.p)]
            if spec.kind == "pcpg"
            else threshold_all(te, scores, ds.trajectory_ids, [spec.p])[spec.p]
        )
        s, v, a = test_rows(ds, subset)
        t0, c0 = time.perf_counter(), time.process_time()
        net = plain_loop(
            raw_cell.states,
            raw_cell.valid,
            raw_cell.actions,
            cell.mean,
            cell.std,
            (cells[0].state_dim, *[cfg.hidden_size] * cfg.hidden_layers, cells[0].n_actions),
            args.plain_epochs,
            64,
            args.plain_lr,
            spec.seed,
            cfg.activation,
        )
        plain_s.append(time.perf_counter() - t0)
        plain_cpu.append(time.process_time() - c0)
        with torch.no_grad():
            logits = net(torch.tensor((s - cell.mean) / cell.std)).masked_fill(
                ~torch.tensor(v), float("-inf")
            )
        acc_p.append(float((logits.argmax(1).numpy() == a).mean()))
        tests.append((i, s, v, a))
        print(
            f"  {cell.key:24s} raw steps {raw_cell.n_rows:6d}  plain {plain_s[-1]:6.2f} s  "
            f"acc plain {acc_p[-1]:.3f}"
        )
    set_threads(args.threads)
    train_cells(cells[:1], BCConfig(epochs=1))  # compile (cached on disk after the first run)
    t0, c0 = time.perf_counter(), time.process_time()
    model = train_cells(cells, cfg)
    batched_s, batched_cpu = time.perf_counter() - t0, time.process_time() - c0
    print(
        f"batched: {len(cells)} models x {cfg.epochs} epochs in {batched_s:.1f} s wall "
        f"({batched_cpu:.1f} CPU-s, {args.threads} threads) = {batched_s / len(cells) * 1e3:.1f} ms/model"
    )

    for i, s, v, a in tests:
        acc_b.append(float((model.predict(s, v, i) == a).mean()))
    per_plain, per_batched = float(np.mean(plain_s)), batched_s / len(cells)
    cpu_plain, cpu_batched = float(np.mean(plain_cpu)), batched_cpu / len(cells)
    print(
        f"plain loop ({args.plain_epochs} epochs, minibatch 64, 1 thread): {per_plain:.2f} s/model "
        f"({cpu_plain:.2f} CPU-s); all {len(cells)} would take {per_plain * len(cells):.0f} s"
    )
    print(
        f"speed ratio per model, wall (plain 1 thread / batched {args.threads} threads): "
        f"{per_plain / per_batched:.0f}x; per CPU-second: {cpu_plain / cpu_batched:.0f}x"
    )
    print(
        f"test accuracy on the sample: batched {np.mean(acc_b):.3f}, plain {np.mean(acc_p):.3f}, "
        f"difference {np.mean(acc_b) - np.mean(acc_p):+.3f}"
    )
    print(
        f"target: all models <= 60 s -> {'met' if batched_s <= 60 else 'MISSED'} ({batched_s:.1f} s); "
        f">= 50x -> {'met' if min(per_plain / per_batched, cpu_plain / cpu_batched) >= 50 else 'MISSED'}"
    )


if __name__ == "__main__":
    main()
