"""Mario Step C: full-batch against minibatch BC, and per-cluster agents from scratch against
agents fine-tuned from the No Clustering one, side by side on held-out episodes.

    uv run python benchmarks/bench_mario_bc.py [--labels labels.json] [--split 1] [--seeds 0,1]

Part 1 trains the No Clustering agents (p = 1, 0.5, 0.1, one seed) of experiments/mario.yaml
two ways: the config's 300 full-batch steps at lr 0.03, and minibatches (``--batch-size``,
``--epochs`` passes, ``--lr``); it prints seconds, the speed ratio and held-out accuracy.

Part 2 needs cluster labels (``--labels``: ``pcpg cluster``'s ``smb/labels.json``, or a run's
file with a ``labels`` list; one per episode; default: k-means on each episode's event
histogram, k = 2).
It trains PCPG and No Clustering at every p with the minibatch settings, then the PCPG
agents again, each started from the No Clustering agent of its p and seed and fine-tuned for
``--finetune-epochs``, and prints PCPG - No Clustering per p for both. ``--split`` picks the
episode split (the run uses 0; choose settings on the others).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from pcpg_dist.common.devices import set_threads
from pcpg_dist.config.experiment import load_config
from pcpg_dist.domains.mario.domain import MarioDomain
from pcpg_dist.pipeline import evaluate_unit, plan_unit
from pcpg_dist.stages.bc import TrainedCells, init_from, train_cells
from pcpg_dist.stages.ranking import fmt

ROOT = Path(__file__).resolve().parents[1]


def histogram_labels(ds, k: int, seed: int) -> np.ndarray:
    from sklearn.cluster import KMeans

    events = ds.states[:, [i for i, n in enumerate(ds.feature_names) if n.startswith("event_")]]
    hist = np.add.reduceat(events, ds.offsets[:-1]) / ds.lengths[:, None]
    return KMeans(k, n_init=10, random_state=seed).fit_predict(hist)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(ROOT / "experiments" / "mario.yaml"))
    ap.add_argument("--labels", type=Path, default=None)
    ap.add_argument("--split", type=int, default=1)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--finetune-epochs", type=int, default=5)
    ap.add_argument("--batch-size", type=int, default=512)
    ap.add_argument("--epochs", type=int, default=20)
    ap.add_argument("--lr", type=float, default=0.01)
    ap.add_argument("--skip-full-batch", action="store_true", help="part 2 only")
    args = ap.parse_args()
    set_threads(args.threads)
    cfg = load_config(args.config)
    cfg = cfg.model_copy(
        update={"ranking": cfg.ranking.model_copy(update={"split_seed": args.split})}
    )
    domain = MarioDomain()
    unit = domain.units(cfg, domain.generate(cfg, show_progress=False))[0]
    ds = unit.dataset
    seeds = [int(s) for s in args.seeds.split(",")]
    ev_cfg = cfg.evaluation.model_copy(update={"figures": False, "corruption_levels": ()})
    mini = cfg.bc.model_copy(
        update={"batch_size": args.batch_size, "epochs": args.epochs, "lr": args.lr}
    )

    def scores(trained, labels, ps):
        ev = evaluate_unit(
            unit,
            labels,
            trained,
            cfg,
            rank_cfg=cfg.ranking.model_copy(update={"ps": ps}),
            eval_cfg=ev_cfg,
            rollouts=False,
            extras=False,
        )
        return ev

    if not args.skip_full_batch:
        ps = (1.0, 0.5, 0.1)
        rank = cfg.ranking.model_copy(update={"ps": ps})
        zeros = np.zeros(ds.n_trajectories, np.int64)
        nc = [
            c
            for c in plan_unit(unit, zeros, cfg, rank_cfg=rank, seeds=seeds[:1], corruption=False)
            if c.spec.kind == "nc"
        ]
        print(
            f"Part 1: No Clustering agents, split {args.split}, seed {seeds[0]}, rows "
            + ", ".join(f"p={fmt(c.spec.p)}: {c.n_rows}" for c in nc)
        )
        runs = {
            f"full batch, {cfg.bc.epochs} steps, lr {cfg.bc.lr} (config)": cfg.bc,
            f"minibatch {args.batch_size}, {args.epochs} passes, lr {args.lr}": mini,
        }
        base_time = None
        for name, bc in runs.items():
            t = time.perf_counter()
            trained = train_cells(nc, bc)
            dt = time.perf_counter() - t
            base_time = base_time or dt
            ev = scores(trained, zeros, ps)
            accs = " ".join(f"p={fmt(p)}: {ev[f'baseline/accuracy/p{fmt(p)}']:.4f}" for p in ps)
            print(f"  {name:48s} {dt:7.1f} s ({base_time / dt:5.1f}x)  accuracy {accs}", flush=True)

    if args.labels is not None:
        raw = json.loads(args.labels.read_text())
        # `pcpg cluster` writes a bare list (<env>/labels.json); a run's files hold {"labels": [...]}
        labels = np.asarray(raw["labels"] if isinstance(raw, dict) else raw, np.int64)
        source = str(args.labels)
    else:
        labels = histogram_labels(ds, cfg.clustering.k, cfg.seed)
        source = f"k-means on event histograms, k={cfg.clustering.k}"
    cells = plan_unit(unit, labels, cfg, seeds=seeds, corruption=False)
    ps = cfg.ranking.ps
    base = train_cells(cells, mini)
    ev = scores(base, labels, ps)
    nc_acc = [ev[f"baseline/accuracy/p{fmt(p)}"] for p in ps]
    scratch = [ev[f"pcpg/accuracy/p{fmt(p)}"] for p in ps]
    pcpg = [c for c in cells if c.spec.kind == "pcpg"]
    tuned = train_cells(
        pcpg, mini.model_copy(update={"epochs": args.finetune_epochs}), init=init_from(pcpg, base)
    )
    merged = base.select([c.key for c in cells if c.spec.kind == "nc"])
    ev2 = scores(TrainedCells.concat([merged, tuned]), labels, ps)
    fine = [ev2[f"pcpg/accuracy/p{fmt(p)}"] for p in ps]
    print(f"Part 2: split {args.split}, seeds {seeds}, labels: {source}")
    print("  p                         " + " ".join(f"{fmt(p):>8s}" for p in ps))
    print("  No Clustering             " + " ".join(f"{a:8.4f}" for a in nc_acc))
    print("  PCPG from scratch         " + " ".join(f"{a:8.4f}" for a in scratch))
    print(
        f"  PCPG fine-tuned ({args.finetune_epochs:2d} ep)   " + " ".join(f"{a:8.4f}" for a in fine)
    )
    print(
        "  scratch - No Clustering   "
        + " ".join(f"{a - b:+8.4f}" for a, b in zip(scratch, nc_acc, strict=True))
    )
    print(
        "  fine-tuned - No Clust.    "
        + " ".join(f"{a - b:+8.4f}" for a, b in zip(fine, nc_acc, strict=True))
    )


if __name__ == "__main__":
    main()
