"""The data a run used, as MLflow dataset inputs (the runs table's Dataset column): generated
data by its content key and generator settings, a user's log by its path and content digest,
contexts ``training`` and ``evaluation``, on the parent and every environment run, once."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from bc_toy import make_dataset

from pcpg_dist.common.errors import DomainError
from pcpg_dist.config import load_config, parse_config
from pcpg_dist.domains import sources
from pcpg_dist.domains.base import Domain, Unit
from pcpg_dist.pipeline.declared import input_key
from pcpg_dist.tracking.children import log_environment
from pcpg_dist.tracking.datasets import data_inputs
from pcpg_dist.tracking.trackers import Tracker

ROOT = Path(__file__).resolve().parents[2]


def inputs_of(client, run_id: str) -> dict[str, tuple[str, str, dict]]:
    """``{context: (name, digest, source)}`` of a run's dataset inputs."""
    found = {}
    for d in client.get_run(run_id).inputs.dataset_inputs:
        context = {t.key: t.value for t in d.tags}["mlflow.data.context"]
        assert context not in found, f"two {context} inputs"
        found[context] = (d.dataset.name, d.dataset.digest, json.loads(d.dataset.source))
    return found


def write_log(path: Path, value: float) -> None:
    rng = np.random.default_rng(0)
    rows = [
        {
            "trajectory": t,
            "step": s,
            "obs": [value + s, 1.0],
            "action": int(rng.integers(2)),
            "reward": 1.0,
        }
        for t in range(6)
        for s in range(5)
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows).to_parquet(path)


def test_generated_data_is_an_input_of_the_parent_and_its_environments_once(tmp_path):
    from mlflow import MlflowClient

    cfg = load_config(ROOT / "experiments" / "quick.yaml")
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    ikey = input_key(cfg)
    toy = make_dataset(n_per_style=5)  # 2 styles x 5
    units = [Unit("E1", toy, np.array([0, 5, 7]))]
    for _ in range(2):  # a rerun adds nothing
        tracker = Tracker.start(cfg, uri, tmp_path / "out", ikey=ikey, units=units)
        child = log_environment(tracker.child_info("E1", "unit", {}), "E1", str(tmp_path), {}, [])
    client = MlflowClient(uri)
    for run_id in (tracker.parent_id, child):
        found = inputs_of(client, run_id)
        assert set(found) == {"training", "evaluation"}
        name, digest, source = found["training"]
        assert (name, digest) == ("gridworld data", ikey)
        assert source["generator"] == "gridworld" and source["seed"] == cfg.seed
        assert source["settings"]["environments"] == cfg.gridworld.environments
        name, digest, source = found["evaluation"]
        assert name == f"gridworld data · held-out {cfg.ranking.test_fraction:g}"
        assert digest != ikey and source["held_out"]["test_fraction"] == cfg.ranking.test_fraction
    lengths = np.diff(toy.offsets)
    profiles = {
        json.loads(d.dataset.profile)["trajectories"]: json.loads(d.dataset.profile)
        for d in client.get_run(tracker.parent_id).inputs.dataset_inputs
    }
    assert profiles[7] == {
        "environments": 1,
        "trajectories": 7,
        "steps": int(lengths.sum() - lengths[[0, 5, 7]].sum()),
    }
    assert profiles[3]["steps"] == int(lengths[[0, 5, 7]].sum())


def test_a_users_log_is_named_by_its_path_and_its_digest_follows_its_content(tmp_path):
    log = tmp_path / "logs" / "plays.parquet"
    write_log(log, 0.0)
    cfg = parse_config(
        {"name": "mine", "domain": "trajectories", "trajectories": {"path": str(log)}}
    )
    first = data_inputs(cfg, input_key(cfg))[0]
    assert (first.name, first.source_type, first.context) == ("plays.parquet", "local", "training")
    assert json.loads(first.source) == {"uri": log.resolve().as_uri()}
    again = data_inputs(cfg, input_key(cfg))[0]
    write_log(log, 5.0)  # the same file, other contents
    changed = data_inputs(cfg, input_key(cfg))[0]
    assert first.digest == again.digest != changed.digest


def test_a_plugins_data_source_is_checked_where_pcpg_receives_it():
    cfg = load_config(ROOT / "experiments" / "quick.yaml")

    class Bad(Domain):
        name = "bad"

        def data_source(self, cfg):
            return {"name": "x", "type": "local", "source": {"uri": float("nan")}}

    with pytest.raises(
        DomainError, match=r"domain 'bad': data_source returned a 'source' that is not JSON-able"
    ):
        sources.data_source(cfg, Bad())

    class NoName(Bad):
        def data_source(self, cfg):
            return {"type": "local", "source": {}}

    with pytest.raises(DomainError, match="no 'name' string"):
        sources.data_source(cfg, NoName())
