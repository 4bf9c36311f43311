"""Experiment: per-cluster agents that share their first layers (trained jointly on every
cluster's steps), against the agents `bc.init: auto` trains and the No Clustering agent.

    uv run python -m benchmarks.zoo.shared_trunk_exp ZOO_DIR [GAME ...] [--share 1 3]
        [--bc-seed 0] [--held-out] [--threads 2] [--set KEY=VALUE] [--labels DIR]

Why: an agent trained on its own cluster alone sees a k-th of the steps. Where the clusters are
styles but each style's data is thin (blind othello with its move features: a perfect
clustering, each agent from scratch level with No Clustering), the agents cannot learn what all
players share; a fine-tune from No Clustering keeps that but also its mixed habits (held-out
goofspiel and connect_four lost 4.5-5.5 points to it). Here the k agents train together: the
first ``share`` layers are one set of weights fitted to every cluster's steps, each agent's
later layers are its own, fitted to its cluster (``share`` = the hidden layers: a shared
feature map and one output layer per style). Each agent is still an ordinary MLP of the same
shape (the shared layers copied into it), with No Clustering's input scaling.

Per game (each built by ``benchmarks.zoo.build`` into ZOO_DIR), seed 0's default clustering
(cached under ``--labels``), p = 1, BC at ``--bc-seed``: the pooled test accuracy of No
Clustering, of what `bc.init: auto` trains (scratch where the styles were found, else checked
fine-tunes), of scratch, and of each shared variant; each as a lead over No Clustering in points
with its paired standard error (trajectories as the units, as ``pcpg/lead_over_nc_se``).
Design games only unless ``--held-out`` (read after a decision, never to choose one).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
import yaml

from benchmarks.zoo.common import design_games
from benchmarks.zoo.finetune_trial_exp import game_setup
from pcpg_dist.common.devices import set_threads
from pcpg_dist.config import parse_config
from pcpg_dist.config.overrides import apply_overrides, parse_overrides
from pcpg_dist.domains import contract
from pcpg_dist.pipeline.units import plan_unit
from pcpg_dist.stages.bc import layer_sizes, train_cells, train_plan
from pcpg_dist.stages.bc.network import INVALID_LOGIT, init_params
from pcpg_dist.stages.bc.trained import TrainedCells
from pcpg_dist.stages.cell_rows import dedupe_rows
from pcpg_dist.stages.clustering.confidence import verdict_of


def shared_agents(cells, nc, cfg, share: int) -> TrainedCells:
    """The per-cluster ``cells`` trained jointly, full batch for ``cfg.epochs`` Adam steps: the
    first ``share`` layers one set of weights, the rest each cell's own; the loss is the mean
    cross-entropy over every cell's steps (weighted by their counts). Inputs scaled as ``nc``'s."""
    sizes = layer_sizes(cells[0].state_dim, cells[0].n_actions, cfg)
    layers = len(sizes) - 1
    start = init_params(sizes, cells[0].spec.seed)
    param = lambda a: torch.nn.Parameter(torch.tensor(np.asarray(a), dtype=torch.float32))  # noqa: E731
    shared = [param(p) for p in start[: 2 * share]]
    own = [param(np.stack([p] * len(cells))) for p in start[2 * share :]]
    data = []
    for c in cells:
        s, v, a, w = dedupe_rows(c.states, c.valid, c.actions, c.weights)
        x = torch.tensor((s - nc.mean) / nc.std, dtype=torch.float32)
        neg = torch.tensor(np.where(v, 0.0, INVALID_LOGIT), dtype=torch.float32)
        data.append((x, neg, torch.tensor(a), torch.tensor(w, dtype=torch.float32)))
    total = sum(float(d[3].sum()) for d in data)
    act = torch.tanh if cfg.activation == "tanh" else torch.relu
    opt = torch.optim.Adam([*shared, *own], lr=cfg.lr, betas=cfg.betas, eps=cfg.eps)

    def forward(j: int, x: torch.Tensor, neg: torch.Tensor) -> torch.Tensor:
        h = x
        for layer in range(layers):
            if layer < share:
                w, b = shared[2 * layer], shared[2 * layer + 1]
            else:
                at = 2 * (layer - share)
                w, b = own[at][j], own[at + 1][j]
            h = h @ w + b
            if layer < layers - 1:
                h = act(h)
        return h + neg

    for _ in range(cfg.epochs):
        loss = (
            sum(
                (
                    torch.nn.functional.cross_entropy(forward(j, x, neg), a, reduction="none") * w
                ).sum()
                for j, (x, neg, a, w) in enumerate(data)
            )
            / total
        )
        opt.zero_grad()
        loss.backward()
        opt.step()
    params = {}
    for layer in range(layers):
        for i, name in enumerate((f"W{layer}", f"b{layer}")):
            if layer < share:
                p = shared[2 * layer + i].detach().numpy()
                params[name] = np.stack([p] * len(cells))
            else:
                params[name] = own[2 * (layer - share) + i].detach().numpy()
    trained = TrainedCells.of_cells(cells, sizes, cfg.activation, params, np.zeros(len(cells)))
    k = len(cells)
    return replace(trained, mean=np.stack([nc.mean] * k), std=np.stack([nc.std] * k))


def game_unit(zoo: Path, name: str, sets: list[str], bc_seed: int):
    """(config, unit) of one game at p = 1, as ``finetune_trial_exp.game_setup`` builds them."""
    raw = yaml.safe_load((zoo / name / "pcpg.yaml").read_text())
    raw["trajectories"]["path"] = str(zoo / name / "labelled")
    raw.update(
        seeds=[bc_seed],
        ranking={"ps": [1.0]},
        evaluation={"corruption_levels": [], "figures": False},
    )
    cfg = parse_config(apply_overrides(raw, parse_overrides(list(sets))))
    (unit,) = contract.units(cfg, contract.generate(cfg, show_progress=False))
    return cfg, unit


def clustered(zoo: Path, name: str, sets: list[str], bc_seed: int, cache: Path):
    """(config, unit, labels, doubted, accuracy): the game at p = 1 and its seed-0 default
    clustering, whose labels and verdict are kept in ``cache`` for the next call."""
    path = cache / ("_".join([name, *sorted(sets)]).replace("/", "-").replace(" ", "") + ".json")
    if path.exists():
        cfg, unit = game_unit(zoo, name, sets, bc_seed)
        saved = json.loads(path.read_text())
        return cfg, unit, np.asarray(saved["labels"]), saved["doubted"], saved["accuracy"]
    cfg, unit, clustering = game_setup(zoo, name, sets, bc_seed)
    doubted = verdict_of(clustering.metrics, cfg.clustering.k).doubts_styles
    accuracy = float(clustering.metrics.get("clustering/accuracy", float("nan")))
    cache.mkdir(parents=True, exist_ok=True)
    saved = {"labels": clustering.labels.tolist(), "doubted": doubted, "accuracy": accuracy}
    path.write_text(json.dumps(saved))
    return cfg, unit, clustering.labels, doubted, accuracy


def step_hits(unit, labels, trained, cell: int, cluster: int):
    """(hits, trajectory index) of every test step of ``cluster`` under agent ``cell``."""
    idx = unit.test_idx[labels[unit.test_idx] == cluster]
    sub = unit.dataset.subset(idx)
    rows = sub.step_rows
    picked = trained.predict(sub.states[rows], sub.valid_mask[rows], cell)
    owner = np.repeat(np.arange(len(idx)) + 1_000_000 * cluster, np.diff(sub.offsets))[rows]
    return (picked == sub.actions[rows]).astype(np.float64), owner


def lead(pairs) -> tuple[float, float, float]:
    """(accuracy, lead over No Clustering, its standard error) from [(hits, nc hits, owner)],
    trajectories as the units (the ratio estimator's linearised error)."""
    hit = np.concatenate([p[0] for p in pairs])
    base = np.concatenate([p[1] for p in pairs])
    owner = np.concatenate([p[2] for p in pairs])
    _, inv = np.unique(owner, return_inverse=True)
    diff = np.bincount(inv, hit - base)
    steps = np.bincount(inv).astype(np.float64)
    total, n = steps.sum(), len(steps)
    d = diff.sum() / total
    se = np.sqrt(((diff - d * steps) ** 2).sum() * n / (n - 1)) / total
    return float(hit.mean()), float(d), float(se)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("zoo", type=Path)
    ap.add_argument("games", nargs="*")
    ap.add_argument("--share", type=int, nargs="+", default=[1, 3])
    ap.add_argument("--bc-seed", type=int, default=0)
    ap.add_argument("--held-out", action="store_true")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--labels", type=Path, default=Path("/tmp/shared_trunk_labels"))
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    set_threads(args.threads)
    games = args.games if args.held_out and args.games else design_games(args.games, ap.error)
    names = ["auto", "scratch", *(f"shared{s}" for s in args.share)]
    print(
        "| game | clustering | verdict doubts | No Clustering | "
        + " | ".join(f"{n}: accuracy, lead ± s.e. (points)" for n in names)
        + " |"
    )
    print("|---|---|---|---|" + "---|" * len(names))
    rows = []
    for name in games:
        cfg, unit, labels, doubted, acc = clustered(
            args.zoo, name, args.set, args.bc_seed, args.labels
        )
        cells = plan_unit(unit, labels, cfg, corruption=False)
        nc_at = next(i for i, c in enumerate(cells) if c.spec.kind == "nc")
        per = sorted(
            (i for i, c in enumerate(cells) if c.spec.kind == "pcpg"), key=lambda i: cells[i].spec.k
        )
        agents = {
            "auto": (train_plan(cells, cfg.bc, doubted), per),
            "scratch": (train_cells(cells, cfg.bc), per),
        }
        for s in args.share:
            trained = shared_agents([cells[i] for i in per], cells[nc_at], cfg.bc, s)
            agents[f"shared{s}"] = (trained, list(range(len(per))))
        base_trained = agents["scratch"][0]
        base = [step_hits(unit, labels, base_trained, nc_at, cells[i].spec.k) for i in per]
        nc_acc = float(np.concatenate([b[0] for b in base]).mean())
        row = {"game": name, "clustering": acc, "doubted": doubted, "nc": nc_acc}
        said = []
        for n, (trained, at) in agents.items():
            if n == "auto":  # train_plan keeps the cells' order
                at = per
            pairs = []
            for j, i in zip(at, per, strict=True):
                hit, owner = step_hits(unit, labels, trained, j, cells[i].spec.k)
                pairs.append((hit, base[len(pairs)][0], owner))
            a, d, se = lead(pairs)
            row[n] = (a, d, se)
            said.append(f"{a:.3f}, {100 * d:+.2f} ± {100 * se:.2f}")
        rows.append(row)
        print(
            f"| {name} | {acc:.3f} | {doubted} | {nc_acc:.3f} | " + " | ".join(said) + " |",
            flush=True,
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
