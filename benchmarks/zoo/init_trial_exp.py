"""Experiment: where the styles are found, can a fair trial tell per cluster whether its agent
should train from scratch or from the No Clustering agent?

    uv run python -m benchmarks.zoo.init_trial_exp ZOO_DIR [GAME ...] [--held-out]
        [--set KEY=VALUE ...] [--shares [0.5]] [--mix 0.5] [--bc-seed 0] [--threads 1]

For each game built by ``benchmarks.zoo.build`` into ZOO_DIR: the default clustering (seed 0) and,
at p = 1, the No Clustering agent and each cluster's agent trained two ways, from scratch (what
``bc.init: auto`` does where the verdict reads "styles found") and fine-tuned from No Clustering
for its full epochs (``bc.init: no_clustering``). Per cluster and share: a trial like
``bc.finetune_check``'s (:func:`pcpg_dist.stages.bc.finetune.trial`: a share of the cluster's
steps held out, a No Clustering agent fitted without them) trains both ways on the cluster's
other steps and picks the one that predicts the held-out steps better (accuracy; at equal
accuracy, cross-entropy); a second choice, without a trial, keeps the one whose loss on the
cluster's own steps is lower. Printed: per cell, both agents' test accuracy and each choice;
per game, PCPG's test accuracy at p = 1 each way and by each choice, No Clustering's, and
scratch's lead over No Clustering with its standard error (paired over the test steps: both
agents scored on each). ``--mix M``: also each agent started at M x its No Clustering agent +
(1 - M) x its seeded init. ``--bc-seed S``: BC at seed S (``pcpg run --set "seeds=[S]"``), the
clustering at seed 0. ``--shares`` with no value: no trial.
Design games only unless ``--held-out`` (held-out games are read after a decision, never to
choose one). ``--set``: config keys (``clustering.move_features=...``) as ``pcpg run --set``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks.zoo.common import design_games
from benchmarks.zoo.finetune_trial_exp import game_setup, hits
from pcpg_dist.common.devices import set_threads
from pcpg_dist.pipeline.units import plan_unit
from pcpg_dist.stages.bc import bases_of, init_from, split_for_init, train_cells
from pcpg_dist.stages.bc.finetune import scores, split_rows, trial
from pcpg_dist.stages.bc.network import init_params, layer_sizes
from pcpg_dist.stages.clustering.confidence import verdict_of


def picks(rest, bases, cfg, share: float) -> dict[int, str]:
    """Per checked cell: "scratch" or "fine-tune", the trial's pick at held-out ``share``."""
    bc = cfg.bc.model_copy(update={"finetune_check": share})
    checked, _, tuned, helds = trial(rest, bc, bases, cfg.bc)
    if not checked:
        return {}
    fits = [split_rows(rest[i], share)[0] for i in checked]
    scratch = train_cells(fits, bc)
    out = {}
    for j, i in enumerate(checked):
        (acc_t, loss_t), (acc_s, loss_s) = scores(tuned, j, helds[j]), scores(scratch, j, helds[j])
        better = acc_t > acc_s or (acc_t == acc_s and loss_t < loss_s)
        out[i] = "fine-tune" if better else "scratch"
    return out


def mixed_starts(rest, init, cfg, mix: float) -> list[list]:
    """Each cell's start ``mix`` x its No Clustering agent + (1 - ``mix``) x its seeded init."""
    sizes = layer_sizes(rest[0].state_dim, rest[0].n_actions, cfg.bc)
    return [
        [mix * a + (1 - mix) * b for a, b in zip(nc, init_params(sizes, c.spec.seed), strict=True)]
        for c, nc in zip(rest, init, strict=True)
    ]


def read_game(args, name: str) -> None:
    """One game's agents, choices and figures, printed."""
    t0 = time.perf_counter()
    cfg, unit, clustering = game_setup(args.zoo, name, args.sets, args.bc_seed)
    cells = plan_unit(unit, clustering.labels, cfg, corruption=False)
    first, rest = split_for_init(cells, cfg.bc, True)
    base = train_cells(first, cfg.bc)
    init = init_from(rest, base)
    agents = {
        "scratch": train_cells(rest, cfg.bc),
        "fine-tune": train_cells(rest, cfg.bc, init),
    }
    if args.mix is not None:
        agents["mix"] = train_cells(rest, cfg.bc, mixed_starts(rest, init, cfg, args.mix))
    bases = bases_of(rest, first)
    said = {share: picks(rest, bases, cfg, share) for share in args.shares}
    acc = clustering.metrics.get("clustering/accuracy", float("nan"))
    verdict = verdict_of(clustering.metrics)
    print(f"\n{name} {' '.join(args.sets)}: clustering {acc:.3f}, verdict {verdict.line()}")
    shares = " | ".join(f"trial {s:g}" for s in args.shares)
    print(f"| cell | test steps | scratch | fine-tuned | by training loss | {shares} |")
    totals = {key: 0.0 for key in [*agents, "loss", *args.shares]}
    nc_at, steps, nc, diff = base.index(bases[0].spec.key), 0, 0.0, []
    for i, c in enumerate(rest):
        got = {key: hits(unit, clustering.labels, t, i, c.spec.k) for key, t in agents.items()}
        nc_hits = hits(unit, clustering.labels, base, nc_at, c.spec.k)
        diff.append(got["scratch"] - nc_hits)
        n, nc = len(nc_hits), nc + nc_hits.sum()
        steps += n
        for key, h in got.items():
            totals[key] += h.sum()
        s_acc, t_acc = got["scratch"].mean(), got["fine-tune"].mean()
        rows = (c.states, c.valid, c.actions, c.weights)
        chosen = {
            "loss": scores(agents["fine-tune"], i, rows)[1] < scores(agents["scratch"], i, rows)[1]
        }
        chosen.update({share: said[share].get(i) == "fine-tune" for share in args.shares})
        cols = []
        for key, tuned in chosen.items():
            totals[key] += (t_acc if tuned else s_acc) * n
            right = tuned == (t_acc > s_acc) or t_acc == s_acc
            cols.append(
                f"{'fine-tune' if tuned else 'scratch'} ({'agrees' if right else 'disagrees'})"
            )
        if "mix" in got:
            cols.append(f"mixed start {got['mix'].mean():.4f}")
        print(f"| {c.spec.key} | {n} | {s_acc:.4f} | {t_acc:.4f} | " + " | ".join(cols) + " |")
    d = np.concatenate(diff)
    print(
        f"{name}: PCPG p=1 scratch {totals['scratch'] / steps:.4f}, fine-tuned "
        f"{totals['fine-tune'] / steps:.4f}, by training loss {totals['loss'] / steps:.4f}, "
        + (f"mixed start ({args.mix}) {totals['mix'] / steps:.4f}, " if "mix" in totals else "")
        + "".join(f"trial {s:g} {totals[s] / steps:.4f}, " for s in args.shares)
        + f"No Clustering {nc / steps:.4f}; scratch - No Clustering {d.mean():+.4f} "
        f"(paired standard error {d.std(ddof=1) / np.sqrt(len(d)):.4f}) "
        f"({time.perf_counter() - t0:.0f} s)",
        flush=True,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("zoo", type=Path, help="a folder from benchmarks.zoo.build")
    ap.add_argument("games", nargs="*")
    ap.add_argument("--shares", type=float, nargs="*", default=[0.5])
    ap.add_argument("--mix", type=float, help="also start each agent between NC and its init")
    ap.add_argument("--bc-seed", type=int, default=0, help="the run's seed (BC); clustering 0")
    ap.add_argument("--held-out", action="store_true", help="held-out games too, read after")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (pcpg run's: its CPUs)")
    args = ap.parse_args()
    set_threads(args.threads)
    games = args.games if args.held_out and args.games else design_games(args.games, ap.error)
    for name in games:
        read_game(args, name)


if __name__ == "__main__":
    main()
