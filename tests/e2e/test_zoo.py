"""The play-style zoo builds and reads back as any user's logs: a subset of its games at CI size,
each through pcpg's own step-table reader, its styles competent and told apart by the ceiling's
panel, its unlabelled copy clustered as the labelled one."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
GAMES = ("cartpole", "tictactoe", "mountaincar")


@pytest.mark.slow
def test_a_subset_of_the_zoo_builds_and_its_styles_are_identifiable(tmp_path):
    from pcpg_dist.config import load_config, parse_config
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.domains import contract
    from pcpg_dist.stages.clustering import cluster
    from pcpg_dist.stages.clustering.ceiling import ceiling_panel

    out = tmp_path / "zoo"
    cmd = [sys.executable, "-m", "benchmarks.zoo.build", *GAMES, "--ci", "--out", str(out)]
    subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, timeout=600)
    for game in GAMES:
        cfg = load_config(out / game / "pcpg.yaml")
        (ds,) = contract.generate(cfg, show_progress=False).values()
        k = cfg.clustering.k
        assert sorted(set(ds.styles.tolist())) == list(range(k)), game
        panel = ceiling_panel(ds, seed=0)
        majority = np.bincount(ds.styles).max() / ds.n_trajectories
        # given their labels the styles are told apart well above guessing the largest style
        assert max(panel.values()) >= majority + 0.15, (game, panel, majority)
        raw = yaml.safe_load((out / game / "pcpg.yaml").read_text())
        raw["trajectories"]["path"] = str(out / game / "unlabelled")
        blind = contract.generate(parse_config(raw), show_progress=False)
        (unlabelled,) = blind.values()
        assert (unlabelled.styles == -1).all()
        method = ClusterConfig(method="visits_kmeans", k=k)
        np.testing.assert_array_equal(
            cluster(ds, method, 0).labels, cluster(unlabelled, method, 0).labels
        )
