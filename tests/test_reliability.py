"""Bad input and tampering: every failure is the project's own clear error, never a traceback,
and nothing the project loads from disk can execute code."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pcpg_dist.cli import main
from pcpg_dist.config import parse_config
from pcpg_dist.domains.gridworld import parse_layout
from pcpg_dist.errors import ConfigError, DataError, LayoutError, PcpgError

ROOT = Path(__file__).resolve().parent.parent

scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
                    st.text(max_size=12))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(st.text(max_size=8), inner, max_size=4)),
                      max_leaves=10)
SECTIONS = ["name", "domain", "seed", "seeds", "gridworld", "pbtg", "clustering", "ranking", "bc",
            "evaluation", "runner", "minidungeons", "mario", "bogus"]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.dictionaries(st.sampled_from(SECTIONS), values, max_size=6))
def test_random_configs_fail_only_with_config_error(data):
    try:
        parse_config(data, base_dir=ROOT / "experiments")
    except ConfigError as e:
        assert "\n" not in str(e)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.text(alphabet=".#SGX12Z\t ", min_size=0, max_size=12), min_size=0, max_size=12))
def test_random_layouts_fail_only_with_layout_error(rows):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            parse_layout("\n".join(rows), name="fuzz.txt")
        except LayoutError as e:
            assert "fuzz.txt" in str(e)


@pytest.mark.parametrize("patch, needle", [
    ({"ranking": {"ps": [1.5]}}, "ranking.ps"),
    ({"ranking": {"ps": [0.0]}}, "ranking.ps"),
    ({"clustering": {"k": 0}}, "clustering.k"),
    ({"bc": {"epochs": -1}}, "bc.epochs"),
])
def test_issue_listed_bad_values_exit_2_and_start_nothing(tmp_path, capsys, patch, needle):
    cfg = {"name": "bad", "gridworld": {"layout_dir": str(ROOT / "experiments" / "gridworlds")}, **patch}
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(cfg))
    assert main(["run", str(path), "--workdir", str(tmp_path / "runs"), "--no-tracking"]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and err.count("\n") == 0
    assert not (tmp_path / "runs").exists()


class Boom:
    def __reduce__(self):
        return (Path("/tmp/pcpg-pwned").touch, ())


def test_tampered_model_file_is_rejected_not_executed(tmp_path):
    from pcpg_dist.bc import BCConfig, TrainedCells, train_cells
    from pcpg_dist.ranking import RankConfig, plan_cells
    from tests.bc_toy import make_dataset

    ds = make_dataset(n_per_style=10)
    cells = plan_cells(ds, ds.styles, np.arange(ds.n_trajectories), RankConfig(ps=(1.0,)), [0])
    trained = train_cells(cells[:1], BCConfig(epochs=5))
    path = trained.save(tmp_path / "cells")
    TrainedCells.load(path)  # the genuine file loads
    sentinel = Path("/tmp/pcpg-pwned")
    sentinel.unlink(missing_ok=True)
    torch.save({"W0": Boom()}, path)  # a pickle payload where tensors should be
    with pytest.raises(DataError, match="unreadable model files"):
        TrainedCells.load(path)
    assert not sentinel.exists()


def test_tampered_cluster_model_is_rejected(tmp_path):
    from pcpg_dist.clustering import ClusterConfig, cluster, load_model
    from pcpg_dist.dataset import Dataset

    rng = np.random.default_rng(0)
    trajs = [{"states": rng.random((4, 2)), "actions": np.zeros(3, int), "valid": np.full(4, 1),
              "rewards": np.zeros(3)} for _ in range(12)]
    ds = Dataset.from_trajectories("toy", "E", 1, trajs, styles=[0] * 12, success=[True] * 12)
    res = cluster(ds, ClusterConfig(method="summary_kmeans", k=2), seed=0)
    res.model.save(tmp_path / "m")
    pt = next((tmp_path / "m").glob("*.pt"))
    pt.write_bytes(pickle.dumps(Boom()))
    with pytest.raises(DataError):
        load_model(tmp_path / "m")
    assert not Path("/tmp/pcpg-pwned").exists()


def test_unwritable_output_is_a_clear_error(tmp_path, capsys):
    """An output path that cannot be created (here: below a plain file) is a one-line error."""
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("x")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump({"name": "w", "gridworld": {"layout_dir": str(ROOT / "experiments" / "gridworlds"),
                                                             "environments": ["E1"]},
                                   "pbtg": {"episodes": 10, "trajectories_per_style": 5, "dataset_per_style": 5}}))
    code = main(["generate", str(cfg), "--out", str(blocker / "data"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and err.startswith("pcpg: error: cannot access") and "not-a-folder" in err


def test_project_errors_are_one_family():
    for cls in (ConfigError, DataError, LayoutError):
        assert issubclass(cls, PcpgError)
