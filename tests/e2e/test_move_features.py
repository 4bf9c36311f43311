"""A user's own game whose move ids say nothing, run end to end with its move features
(``clustering.move_features``): the log as a step table, the user's function named in the config,
``pcpg``'s default clusterer, ceiling, BC and summary, through Ray."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import yaml
from move_toy import N_ACTIONS, players

from pcpg_dist.config import load_config


def step_table(n_per_style: int, seed: int) -> pd.DataFrame:
    ds = players(n_per_style, seed)
    rows = []
    for i in range(ds.n_trajectories):
        for t, row in enumerate(range(ds.offsets[i], ds.offsets[i + 1])):
            rows.append(
                {
                    "trajectory": i,
                    "t": t,
                    "s0": float(ds.states[row, 0]),
                    "s1": float(ds.states[row, 1]),
                    "action": int(ds.actions[row]),
                    "valid": ds.valid[row].tolist(),
                    "style": int(ds.styles[i]),
                }
            )
    return pd.DataFrame(rows)


@pytest.mark.slow
def test_own_game_with_move_features_end_to_end(ray_session, tmp_path) -> None:
    from rich.console import Console

    from pcpg_dist.api.run import run_experiment
    from pcpg_dist.reporting.summary import method_used, print_summary
    from pcpg_dist.stages.clustering.confidence import verdict_of

    path = tmp_path / "moves.parquet"
    step_table(25, seed=11).to_parquet(path, index=False)
    raw = {
        "name": "own_moves",
        "domain": "trajectories",
        "seeds": [0],
        "trajectories": {"path": str(path), "score": "length", "n_actions": N_ACTIONS},
        "clustering": {"k": 3, "move_features": "tests.move_toy:features"},
        "ranking": {"ps": [1.0]},
        "bc": {"epochs": 20, "hidden_size": 8},
        "evaluation": {"corruption_levels": [], "figures": False},
    }
    (tmp_path / "cfg.yaml").write_text(yaml.safe_dump(raw))
    cfg = load_config(tmp_path / "cfg.yaml")
    result = run_experiment(cfg, workdir=tmp_path / "runs", track=False, show_progress=False)
    m = result.metrics
    assert m["clustering/auto_chose_choice_mix"] == 1.0
    # the terminal's method column and the verdict's reasons say so
    assert method_used("bag_auto", m) == "bag_auto -> choice_mix"
    assert "choice_mix" in " ".join(verdict_of(m, 3).reasons)
    assert m["clustering/accuracy"] >= 0.95
    # the panel has the supervised choice models; the default is within 3 points of them
    assert m["clustering/ceiling_choice_likelihood"] >= 0.95
    assert m["clustering/accuracy"] >= m["clustering/ceiling"] - 0.03
    assert m["clustering/ceiling_linear_bags"] < 0.8  # the ids and states alone say little
    # what each cluster weighs, named by the function's names, in a table and on the terminal
    (env,) = result.clustering
    weights = pd.read_csv(result.out_dir / "summary" / env / "style_weights.csv")
    assert list(weights.columns) == ["feature", "k0", "k1", "k2"]
    assert list(weights["feature"]) == ["first", "second", "third", "fourth"]
    console = Console(record=True, width=400)
    print_summary(result, console, method="bag_auto")
    said = console.export_text()
    assert "bag_auto -> choice_mix" in said and "what sets each cluster apart" in said
    for name in ("first", "second", "third"):  # each style's own feature sets its cluster apart
        assert f"{name} +" in said
    # `pcpg cluster` (Step A alone) writes the same table beside its model
    from pcpg_dist.api.cluster import cluster

    cluster(cfg, tmp_path / "step_a", show_progress=False)
    alone = pd.read_csv(tmp_path / "step_a" / env / "style_weights.csv")
    pd.testing.assert_frame_equal(alone, weights)
    summary = json.loads((result.out_dir / "summary" / "metrics.json").read_text())
    assert np.isclose(summary["clustering/accuracy"], m["clustering/accuracy"])
