"""Mario as a registered domain: the human play log, no labels, no simulator.

One unit with a seeded episode split; its valid actions are the event ids seen in the training
episodes (predicting an event never seen in training can only be a guess). The evaluation extra
is a per-cluster profile (lengths, deaths, kills, coins per step) as a table, figure and metrics.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pcpg_dist.domains.base import Domain, FanOut, Unit
from pcpg_dist.domains.defaults import in_process
from pcpg_dist.domains.mario.paper import PAPER
from pcpg_dist.domains.mario.settings import SECTIONS


class MarioDomain(Domain):
    name = "mario"
    sections = SECTIONS
    paper = PAPER

    def data_key(self, cfg) -> list[Any]:
        from pcpg_dist.common.files import sha256_file

        log = cfg.mario.path
        return [
            self.name,
            cfg.mario,
            sha256_file(log) if log is not None and log.is_file() else "shipped",
        ]

    def data_source(self, cfg) -> dict[str, Any]:
        from pcpg_dist.domains.mario.log import SHIPPED_PATH

        log = cfg.mario.path
        if log is None:
            return {
                "name": "mario play logs (shipped)",
                "type": "package",
                "source": {"uri": "pcpg_dist/" + "/".join(SHIPPED_PATH)},
            }
        return {
            "name": Path(log).name,
            "type": "local",
            "source": {"uri": Path(log).resolve().as_uri()},
        }

    def generate(self, cfg, show_progress: bool = True, fan_out: FanOut = in_process):
        from pcpg_dist.domains.mario.log import load

        result = load(cfg.mario)
        if result.skipped:
            from pcpg_dist.common.progress import console

            console.print(f"mario: {result.summary()}")
        return {result.dataset.env: result.dataset}

    def units(self, cfg, datasets) -> list[Unit]:
        from pcpg_dist.domains.defaults import split_trajectories
        from pcpg_dist.domains.mario.log import valid_mask_from, with_valid

        units = []
        for env, ds in datasets.items():
            train_idx, test_idx = split_trajectories(
                ds.n_trajectories, cfg.ranking.test_fraction, cfg.ranking.split_seed
            )
            units.append(Unit(env, with_valid(ds, valid_mask_from(ds.subset(train_idx))), test_idx))
        return units

    def extras(self, cfg, unit: Unit, labels, trained, out: Path) -> dict[str, float]:
        from pcpg_dist.domains.mario.log import cluster_profile, plot_profile

        profile = cluster_profile(unit.dataset, labels)
        profile.to_csv(out / "cluster_profile.csv")
        profile.to_json(out / "cluster_profile.json", orient="index", indent=1)
        plot_profile(profile, out / "cluster_profile.png")
        metrics = {}
        for k, row in profile.iterrows():  # so the MLflow UI can chart and compare styles
            metrics.update({f"profile/{col}/k{k}": float(v) for col, v in row.items()})
        return metrics
