"""ranking.style_margin end to end (`pcpg run`): on E3, where ~7 % of the trajectories are short
walks to G that three styles' actions fit alike (docs/results.md), ranking them last raises the
small-p PCPG accuracy and leaves p = 1 (every trajectory kept) exactly as it was."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from pcpg_dist.api.run import run_experiment
from pcpg_dist.config import load_config

ROOT = Path(__file__).resolve().parents[2]

E3 = {
    "name": "e3",
    "seed": 0,
    "seeds": [0, 1],
    "gridworld": {
        "layout_dir": str(ROOT / "pcpg_dist" / "data" / "gridworld"),
        "environments": ["E3"],
    },
    "pbtg": {"episodes": 20000, "trajectories_per_style": 1000, "dataset_per_style": 250},
    # the ranking is under test: no supervised ceiling, no confidence refits
    "clustering": {"k": 4, "ceiling": False, "confidence_runs": 0},
    "ranking": {"ps": [1.0, 0.1]},
    "bc": {"epochs": 1000},
    "evaluation": {"rollouts_per_policy": 10, "corruption_levels": [0.0], "figures": False},
}


@pytest.mark.slow
def test_ranking_ambiguous_trajectories_last_raises_small_p_accuracy(ray_session, tmp_path):
    results = {}
    for margin in (0.0, 1.0):
        path = tmp_path / f"e3_{margin}.yaml"
        path.write_text(
            yaml.safe_dump({**E3, "ranking": {**E3["ranking"], "style_margin": margin}})
        )
        # one workdir: the data and the clustering are computed once and shared by both runs
        results[margin] = run_experiment(
            load_config(path), workdir=tmp_path / "runs", track=False, show_progress=False
        ).metrics
    paper, aware = results[0.0], results[1.0]
    assert "ranking/ranked_last" not in paper
    assert 0.02 < aware["ranking/ranked_last"] < 0.2, aware["ranking/ranked_last"]
    assert aware["pcpg/accuracy/p1"] == paper["pcpg/accuracy/p1"]  # p = 1 keeps everything
    assert aware["pcpg/accuracy/p0.1"] >= paper["pcpg/accuracy/p0.1"] + 0.01, (
        paper["pcpg/accuracy/p0.1"],
        aware["pcpg/accuracy/p0.1"],
    )
