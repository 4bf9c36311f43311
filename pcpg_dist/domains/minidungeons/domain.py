"""MiniDungeons as a registered domain: six proxies on 13 levels, trained on 7, tested on 6.

One Ray task per (level, proxy) generates the data; all levels form one unit whose test set is
the held-out levels (the paper trains and tests on different levels). Step A sees each level's
states standardised within the level: in raw features a level's size swamps play-style (LSTM+DEC
0.44 accuracy against the proxies; per level 0.83). Agents are rolled out on the held-out levels,
and their outcomes are tabled beside their proxy's.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from pcpg_dist.domains.base import Domain, DomainHooks, FanOut, Unit, standardised
from pcpg_dist.domains.defaults import in_process
from pcpg_dist.domains.minidungeons.paper import PAPER
from pcpg_dist.domains.minidungeons.settings import SECTIONS


def _part(level: str, proxy: int, runs: int, seed: int, noise: tuple[float, float], max_steps: int):
    from pcpg_dist.domains.minidungeons import generate_trajectories, part_seed

    return generate_trajectories(
        level, proxy, runs, part_seed(seed, level, proxy), noise, max_steps
    )


def held_out_rollout(cfg, policy, n: int, rng: np.random.Generator):
    """``n`` episodes spread evenly over the held-out levels."""
    from pcpg_dist.dataset import Dataset
    from pcpg_dist.domains.minidungeons import rollout

    levels = cfg.minidungeons.test_levels
    counts = [n // len(levels) + (i < n % len(levels)) for i in range(len(levels))]
    parts = [
        rollout(lv, policy, c, rng, max_steps=cfg.minidungeons.max_steps)
        for lv, c in zip(levels, counts, strict=True)
        if c
    ]
    return Dataset.concat(parts)


class MiniDungeonsDomain(Domain):
    name = "minidungeons"
    sections = SECTIONS
    paper = PAPER

    def generate(self, cfg, show_progress: bool = True, fan_out: FanOut = in_process):
        from pcpg_dist.dataset import Dataset
        from pcpg_dist.domains.minidungeons import N_PROXIES

        md = cfg.minidungeons
        levels = [*md.train_levels, *md.test_levels]
        calls = [
            (lv, p, md.runs_per_level, cfg.seed, (md.noise_min, md.noise_max), md.max_steps)
            for lv in levels
            for p in range(N_PROXIES)
        ]
        parts = fan_out(_part, calls, "proxies (level, proxy)", show_progress=show_progress)
        return {
            lv: Dataset.concat(parts[i * N_PROXIES : (i + 1) * N_PROXIES], renumber=True)
            for i, lv in enumerate(levels)
        }

    def units(self, cfg, datasets) -> list[Unit]:
        from pcpg_dist.common.errors import DataError
        from pcpg_dist.dataset import Dataset

        md = cfg.minidungeons
        missing = [lv for lv in (*md.train_levels, *md.test_levels) if lv not in datasets]
        if missing:
            raise DataError(f"minidungeons data has no level {missing[0]!r}")
        parts = [datasets[lv] for lv in (*md.train_levels, *md.test_levels)]
        joined = replace(Dataset.concat(parts), env="levels")
        n_train = sum(datasets[lv].n_trajectories for lv in md.train_levels)
        scaled = replace(Dataset.concat([standardised(p) for p in parts]), env="levels")
        return [
            Unit("levels", joined, np.arange(n_train, joined.n_trajectories), scaled, "per-level-z")
        ]

    def hooks(self, cfg, unit: str) -> DomainHooks:
        return DomainHooks(rollout=lambda policy, n, rng: held_out_rollout(cfg, policy, n, rng))

    def extras(self, cfg, unit: Unit, labels, trained, out: Path) -> dict[str, float]:
        """Outcomes (kills, treasures, exits, ...) of each cluster's agent beside its proxy's."""
        import pandas as pd

        from pcpg_dist.domains.minidungeons import PROXY_NAMES, outcome_stats
        from pcpg_dist.stages.evaluation import rollout_rng, style_of_clusters

        dataset, test_idx = unit.dataset, unit.test_idx
        style = style_of_clusters(dataset, labels, cfg.clustering.k)
        seed, p = min(cfg.seeds), max(cfg.ranking.ps)
        rows, metrics = [], {}
        proxies = outcome_stats(dataset.subset(test_idx)).assign(style=dataset.styles[test_idx])
        for k in range(cfg.clustering.k):
            key = f"k{k}-p{p:g}-s{seed}"
            if key not in trained.keys:
                continue
            roll = held_out_rollout(
                cfg,
                trained.policy(key, greedy=cfg.evaluation.greedy),
                cfg.evaluation.rollouts_per_policy,
                rollout_rng(cfg.evaluation.rollout_seed, key),
            )  # rollouts.csv's episodes
            agent = outcome_stats(roll).mean(numeric_only=True)
            own = proxies[proxies["style"] == style[k]].mean(numeric_only=True)
            for stat in agent.index.drop(["trajectory", "style"], errors="ignore"):
                rows.append(
                    {
                        "cluster": k,
                        "proxy": PROXY_NAMES[style[k]],
                        "stat": stat,
                        "agent": float(agent[stat]),
                        "proxy_value": float(own.get(stat, np.nan)),
                    }
                )
                metrics[f"outcome/{stat}/k{k}"] = float(agent[stat])
        table = pd.DataFrame(rows)
        table.to_csv(out / "outcomes.csv", index=False)
        table.to_json(out / "outcomes.json", orient="records", indent=1)
        return metrics

    def manifest(self, cfg, datasets) -> dict[str, Any]:
        return {"seed_entropy": {"base": cfg.seed}}
