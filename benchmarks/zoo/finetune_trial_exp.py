"""Experiment: does the fine-tune check's trial pick the agent that does better on test steps?

    uv run python -m benchmarks.zoo.finetune_trial_exp ZOO_DIR [GAME ...] [--shares 0.2 0.5]
        [--held-out] [--threads 1]

For each design game (held-out games are refused: this chose ``bc.finetune_check``), built by
``benchmarks.zoo.build`` into ZOO_DIR: the default clustering (seed 0), the No Clustering agent
and each cluster's fine-tune from it at p = 1, as ``bc.init: auto`` trains them for a doubted
unit. Per cluster, and per share of held-out steps: the fair trial's verdict (the rule of
:func:`pcpg_dist.stages.bc.finetune.kept_starts`, fine-tune or No Clustering) beside which of
the two agents is more accurate on that cluster's test steps. Printed: each cell, and per share
how many verdicts agree; then, at the largest share, each trial's margins: the fine-tune's
accuracy less No Clustering's on the held-out steps, the paired difference's standard error, and
both agents' cross-entropy there (what a stricter rule would read). ``--held-out``: also the
held-out games, read after a decision (never to choose one).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import yaml

from benchmarks.zoo.common import design_games
from pcpg_dist.common.devices import set_threads
from pcpg_dist.config import parse_config
from pcpg_dist.config.overrides import apply_overrides, parse_overrides
from pcpg_dist.domains import contract
from pcpg_dist.pipeline.units import cluster_unit, plan_unit
from pcpg_dist.stages.bc import bases_of, finetune_config, init_from, split_for_init, train_cells
from pcpg_dist.stages.bc.finetune import kept_of, scores, trial


def game_setup(zoo: Path, name: str, sets: list[str] = (), bc_seed: int = 0):
    """(config, unit, clustering) of one game at p = 1: clustering at seed 0, BC at
    ``bc_seed`` (a run's ``seeds``, as ``pcpg run --set "seeds=[S]"``); ``sets``: config keys
    as ``pcpg run --set``."""
    raw = yaml.safe_load((zoo / name / "pcpg.yaml").read_text())
    raw["trajectories"]["path"] = str(zoo / name / "labelled")
    raw.update(
        seeds=[bc_seed],
        ranking={"ps": [1.0]},
        evaluation={"corruption_levels": [], "figures": False},
    )
    cfg = parse_config(apply_overrides(raw, parse_overrides(list(sets))))
    (unit,) = contract.units(cfg, contract.generate(cfg, show_progress=False))
    return cfg, unit, cluster_unit(unit, cfg.clustering, cfg.seed, ceiling=False)


def game_cells(zoo: Path, name: str):
    """(unit, labels, No Clustering agents, fine-tuned cells, their agents, bases, config)."""
    cfg, unit, clustering = game_setup(zoo, name)
    labels = clustering.labels
    cells = plan_unit(unit, labels, cfg, corruption=False)
    first, rest = split_for_init(cells, cfg.bc, True)
    base = train_cells(first, cfg.bc)
    tuned = train_cells(rest, finetune_config(cfg.bc), init_from(rest, base))
    return unit, labels, base, rest, tuned, bases_of(rest, first), cfg


def hits(unit, labels, trained, cell: int, cluster: int) -> np.ndarray:
    """1.0 where ``trained``'s agent ``cell`` predicts a test step of ``cluster``, else 0.0."""
    sub = unit.dataset.subset(unit.test_idx[labels[unit.test_idx] == cluster])
    rows = sub.step_rows
    picked = trained.predict(sub.states[rows], sub.valid_mask[rows], cell)
    return (picked == sub.actions[rows]).astype(np.float64)


def test_accuracy(unit, labels, trained, cell: int, cluster: int) -> tuple[float, int]:
    """(accuracy on the test steps of one cluster, their count)."""
    hit = hits(unit, labels, trained, cell, cluster)
    return float(hit.mean()), len(hit)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("zoo", type=Path, help="a folder from benchmarks.zoo.build")
    ap.add_argument("games", nargs="*")
    ap.add_argument("--shares", type=float, nargs="+", default=[0.2, 0.5])
    ap.add_argument("--held-out", action="store_true", help="held-out games too, read after")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (pcpg run's: its CPUs)")
    args = ap.parse_args()
    set_threads(args.threads)
    agree = {share: [0, 0] for share in args.shares}
    print(
        "| game | cell | test steps | fine-tune on test | No Clustering on test | "
        + " | ".join(f"trial, {s:g} held out" for s in args.shares)
        + " |"
    )
    print("|---|---|---|---|---|" + "---|" * len(args.shares))
    games = args.games if args.held_out and args.games else design_games(args.games, ap.error)
    margins = []
    for name in games:
        unit, labels, base, rest, tuned, bases, cfg = game_cells(args.zoo, name)
        nc_at = [base.index(b.spec.key) for b in bases]
        trials = {}  # share -> one trial's outcome: its verdicts, and its margins at the largest
        for share in args.shares:
            ft_cfg = finetune_config(cfg.bc).model_copy(update={"finetune_check": share})
            trials[share] = trial(rest, ft_cfg, bases, cfg.bc)
        verdicts = {share: kept_of(*outcome) for share, outcome in trials.items()}
        for i, c in enumerate(rest):
            ft, n = test_accuracy(unit, labels, tuned, i, c.spec.k)
            nc, _ = test_accuracy(unit, labels, base, nc_at[i], c.spec.k)
            said = []
            for share in args.shares:
                pick = "No Clustering" if i in verdicts[share] else "fine-tune"
                right = (pick == "fine-tune") == (ft > nc) or np.isclose(ft, nc)
                agree[share][0] += right
                agree[share][1] += 1
                said.append(f"{pick} ({'agrees' if right else 'disagrees'})")
            print(
                f"| {name} | {c.spec.key} | {n} | {ft:.3f} | {nc:.3f} | " + " | ".join(said) + " |",
                flush=True,
            )
        margins += [
            (name, rest[i].spec.key, *m) for i, m in trial_margins(trials[max(args.shares)])
        ]
    for share, (right, total) in agree.items():
        print(f"share {share:g}: the trial agrees with the test steps on {right} of {total} cells")
    print(
        f"\n| game | cell | held-out steps ({max(args.shares):g}) | fine-tune - NC accuracy | "
        "its standard error | fine-tune cross-entropy | NC cross-entropy |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, key, n, diff, se, loss, loss0 in margins:
        print(f"| {name} | {key} | {n:.0f} | {diff:+.4f} | {se:.4f} | {loss:.3f} | {loss0:.3f} |")


def trial_margins(outcome):
    """[(cell index, (held-out steps, accuracy difference, its standard error over the paired
    steps, the fine-tune's cross-entropy, No Clustering's))] of each checked cell of one
    :func:`~pcpg_dist.stages.bc.finetune.trial`'s ``outcome``."""
    checked, trial_bases, tuned, helds = outcome
    out = []
    for j, i in enumerate(checked):
        states, valid, actions, w = helds[j]
        d = (tuned.predict(states, valid, j) == actions).astype(float)
        d -= trial_bases.predict(states, valid, j) == actions
        total = w.sum()
        diff = float(w @ d / total)
        se = float(np.sqrt(w @ (d - diff) ** 2 / (total * (total - 1))))
        loss, loss0 = scores(tuned, j, helds[j])[1], scores(trial_bases, j, helds[j])[1]
        out.append((i, (total, diff, se, loss, loss0)))
    return out


if __name__ == "__main__":
    main()
