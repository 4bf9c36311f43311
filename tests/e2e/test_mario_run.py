"""`pcpg run` on real Mario play: 60 human episodes (cut to their first 150 steps), no labels.

What the Mario issue asks of a run: PCPG and No Clustering accuracy per p above the majority-class
baseline, a per-cluster profile (table, figure, MLflow metrics), the data-side Fig. 6 and the
cross-accuracy matrix, all from episodes split whole between training and test.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from pcpg_dist.api.run import run_experiment
from pcpg_dist.config import load_config
from pcpg_dist.domains.mario import log as mario
from pcpg_dist.stages.data import generate, units
from tests.reference.configs import small_mario_log

EPISODES, STEPS = 60, 150


def small_log(path: Path) -> Path:
    """The shipped log's first EPISODES episodes, each cut to its first STEPS steps."""
    return small_mario_log(path, EPISODES, STEPS)


@pytest.fixture(scope="module")
def mario_cfg(tmp_path_factory):
    where = tmp_path_factory.mktemp("mario")
    raw = {
        "name": "mario_small",
        "domain": "mario",
        "seed": 0,
        "seeds": [0, 1],
        "mario": {
            "path": str(small_log(where / "small.log")),
            "event": "onehot",
            "counters": True,
            "increments": True,
        },
        # experiments/mario.yaml's pipeline: policy-mixture clusters, minibatch BC, per-cluster
        # agents fine-tuned from the No Clustering one
        "clustering": {"method": "policy_mix", "policy_start": "counters", "k": 2},
        "ranking": {"ps": [1.0, 0.5]},
        "bc": {
            "hidden_layers": 2,
            "hidden_size": 16,
            "batch_size": 512,
            "epochs": 20,
            "lr": 0.01,
            "init": "no_clustering",
            "finetune_epochs": 5,
        },
    }
    (where / "mario.yaml").write_text(yaml.safe_dump(raw))
    return load_config(where / "mario.yaml")


@pytest.fixture(scope="module")
def mario_run(ray_session, mario_cfg, tmp_path_factory):
    work = tmp_path_factory.mktemp("work")
    return run_experiment(
        mario_cfg,
        workdir=work / "runs",
        tracking_uri=f"sqlite:///{work / 'mlflow.db'}",
        show_progress=False,
        command="pcpg run mario.yaml",
    )


def test_episodes_are_split_whole(mario_cfg) -> None:
    (unit,) = units(mario_cfg, generate(mario_cfg, show_progress=False))
    ds = unit.dataset
    assert ds.n_trajectories == EPISODES and ds.lengths.max() == STEPS
    train = np.setdiff1d(np.arange(EPISODES), unit.test_idx)
    assert len(unit.test_idx) == round(0.2 * EPISODES)
    assert not set(ds.trajectory_ids[train]) & set(ds.trajectory_ids[unit.test_idx])
    # only events seen as a training target are valid, in training and test rows alike
    seen = np.unique(ds.subset(train).actions[ds.subset(train).actions >= 0])
    assert (ds.valid_mask.sum(axis=1) == len(seen)).all()


@pytest.mark.slow
def test_mario_run_beats_the_majority_class_and_profiles_styles(mario_run, mario_cfg) -> None:
    m = mario_run.metrics
    for p in ("1", "0.5"):
        majority = m[f"majority/accuracy/p{p}"]
        assert 0.1 < majority < 0.3  # the most frequent next event is ~20 % of the steps
        # the current event alone predicts the next one ~30 % of the time
        assert m[f"pcpg/accuracy/p{p}"] > majority + 0.03, p
        assert m[f"baseline/accuracy/p{p}"] > majority, p
    assert m["random/accuracy"] < 0.05

    smb = mario_run.out_dir / "summary" / "smb"
    profile = pd.read_csv(smb / "cluster_profile.csv", index_col="cluster")
    assert list(profile.index) == [0, 1] and profile["size"].sum() == EPISODES
    assert (profile[list(mario.RATE_COLUMNS)] >= 0).all().all()
    for k in (0, 1):
        assert m[f"profile/jumps_per_step/k{k}"] == pytest.approx(profile.loc[k, "jumps_per_step"])
    lengths = pd.read_csv(smb / "subset_length.csv")
    assert set(lengths["method"]) == {"pcpg", "nc"} and (lengths["mean"] <= STEPS).all()
    nc = lengths[lengths.method == "nc"].set_index("p")
    assert nc.loc[1.0, "n"] == EPISODES - round(0.2 * EPISODES)
    for name in (
        "cluster_profile.png",
        "subset_length.png",
        "cross_accuracy.png",
        "accuracy_vs_p.png",
    ):
        assert (smb / name).read_bytes()[:4] == b"\x89PNG", name
    cross = pd.read_csv(smb / "cross_accuracy.csv", index_col=0)
    assert cross.shape == (2, 2) and ((cross > 0.05) & (cross < 0.6)).all().all()
    assert (
        json.loads((mario_run.out_dir / "summary" / "metrics.json").read_text())[
            "smb/majority/accuracy"
        ]
        > 0
    )


@pytest.mark.slow
def test_a_split_that_changes_the_clustering_input_gets_its_own_clustering(
    ray_session, mario_cfg, tmp_path
) -> None:
    """Mario's clustering input (its valid-event mask) comes from the training episodes, so from the
    split; the clustering cache key held only the settings, so a rerun (or a sweep point) with
    another ranking.split_seed reused the first split's clustering."""
    fast = {
        "ranking.test_fraction": 0.9,
        "seeds": [0],
        "clustering.em_iterations": 2,
        "clustering.policy_steps": 10,
        "clustering.confidence_runs": 0,  # the cache key is under test, not the confidence
        "bc.epochs": 2,
        "bc.finetune_epochs": 1,
        "evaluation.corruption_levels": [],
        "evaluation.figures": False,
    }

    def cfg(split_seed: int):
        from pcpg_dist.config import ExperimentConfig
        from pcpg_dist.config.overrides import apply_overrides

        raw = apply_overrides(
            mario_cfg.model_dump(mode="json"), {**fast, "ranking.split_seed": split_seed}
        )
        return ExperimentConfig.model_validate(raw)

    masks = [
        units(cfg(s), generate(cfg(s), show_progress=False))[0].clustered.valid.any(axis=0)
        for s in (0, 2)
    ]
    assert (masks[0] != masks[1]).any()  # the two splits' training episodes saw different events
    work = tmp_path / "runs"
    first = run_experiment(cfg(0), workdir=work, tracking_uri=None, show_progress=False)
    second = run_experiment(cfg(2), workdir=work, tracking_uri=None, show_progress=False)
    again = run_experiment(cfg(2), workdir=work, tracking_uri=None, show_progress=False)
    assert first.computed["clustering"] == second.computed["clustering"] == 1
    assert again.computed["clustering"] == 0
    fresh = run_experiment(
        cfg(2), workdir=tmp_path / "fresh", tracking_uri=None, show_progress=False
    )
    assert second.metrics["clustering/size_min_frac"] == fresh.metrics["clustering/size_min_frac"]
