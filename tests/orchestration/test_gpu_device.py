"""clustering.device / bc.device and Ray's GPUs: which tasks ask for one, and the one-line refusals.

A stage on ``cuda`` asks Ray for ``runner.gpus_per_task`` GPUs, so that its tasks run on nodes
with a GPU and share it; on a cluster without a GPU ``cuda`` is refused before anything starts
and ``auto`` is the CPU, with the CPU's numbers. (A real GPU run is benchmarks/gpu_check.sh; CI has no GPU.)
"""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from pcpg_dist.common.devices import resolve_device, stage_gpus
from pcpg_dist.common.errors import ConfigError
from pcpg_dist.config.stages import BCConfig, ClusterConfig, RunnerConfig


def test_stage_gpus_asks_only_where_a_stage_is_on_a_gpu():
    assert stage_gpus("cpu", 0.25, 8, "clustering.device") == 0.0
    assert stage_gpus("auto", 0.25, 0, "clustering.device") == 0.0  # no GPU anywhere: the CPU
    assert stage_gpus("auto", 0.25, 1, "clustering.device") == 0.25
    assert stage_gpus("cuda", 2, 4, "bc.device") == 2.0
    with pytest.raises(
        ConfigError, match=r"^bc.device is 'cuda' but no Ray node has a GPU; use 'cpu'"
    ):
        stage_gpus("cuda", 0.25, 0, "bc.device")
    with pytest.raises(
        ConfigError,
        match=r"gpus_per_task: 2 GPUs per task, but the largest Ray node has 1; "
        r"set it to at most 1$",
    ):
        stage_gpus("cuda", 2, 1, "clustering.device")


def test_gpus_per_task_is_a_fraction_or_whole():
    assert RunnerConfig(gpus_per_task=0.5).gpus_per_task == 0.5
    assert RunnerConfig(gpus_per_task=3).gpus_per_task == 3
    for bad in (0, -1, 1.5):
        with pytest.raises(ValidationError):
            RunnerConfig(gpus_per_task=bad)


@pytest.mark.skipif(
    __import__("torch").cuda.is_available(), reason="checks the refusal without a GPU"
)
def test_cuda_without_a_gpu_is_one_line_and_auto_is_the_cpu():
    with pytest.raises(
        ConfigError, match=r"^clustering.device is 'cuda' but torch sees no GPU here"
    ):
        resolve_device("cuda", "clustering.device")
    assert resolve_device("auto", "clustering.device").type == "cpu"


def test_policy_mix_auto_is_the_cpu_fit_where_no_gpu_is_seen():
    """MiniDungeons' clusterer with ``device: auto``: on a machine without a GPU, the CPU's labels."""
    import torch
    from stages.test_policy_mix import FAST, goal_seekers

    from pcpg_dist.stages.clustering import cluster, clustering_metrics

    goals = goal_seekers(
        40, seed=7
    )  # as test_policy_mix: EM finds the styles from a start near chance
    cpu = cluster(goals, ClusterConfig(**FAST), seed=0)
    auto = cluster(goals, ClusterConfig(**FAST, device="auto"), seed=0)
    assert clustering_metrics(goals.styles, cpu.labels)["accuracy"] >= 0.95
    if not torch.cuda.is_available():
        assert np.array_equal(cpu.labels, auto.labels)
        assert np.allclose(cpu.margins, auto.margins)
    else:  # a GPU sums in another order: the same clusters, not necessarily the same last bits
        assert clustering_metrics(goals.styles, auto.labels)["accuracy"] >= 0.95


def test_only_a_clustering_that_trains_a_network_asks_for_a_gpu():
    """``bag_auto`` trains a network only where it falls back to policy_mix (continuous states)."""
    from stages.test_policy_mix import goal_seekers

    from pcpg_dist.dataset import Dataset
    from pcpg_dist.stages.clustering.auto import needs_network

    continuous = goal_seekers(5, seed=0)
    rng = np.random.default_rng(0)
    grid = [
        {
            "states": rng.integers(0, 3, size=(6, 2)).astype(float),
            "actions": rng.integers(0, 4, 5),
            "valid": np.full(6, 15),
            "rewards": np.zeros(5),
        }
        for _ in range(20)
    ]  # 9 distinct states
    discrete = Dataset.from_trajectories("toy", "grid", 4, grid, [0] * 20, [True] * 20)
    auto = ClusterConfig(method="bag_auto")
    # on discrete states bag_auto fits policy_mix beside greedy_mix to choose by stability, unless
    # no refits are asked for (then greedy_mix alone)
    assert needs_network(auto, continuous) and needs_network(auto, discrete)
    alone = ClusterConfig(method="bag_auto", confidence_runs=0)
    assert needs_network(alone, continuous) and not needs_network(alone, discrete)
    for method, neural in (
        ("lstm_dec", True),
        ("policy_mix", True),
        ("greedy_mix", False),
        ("bag_kmeans", False),
    ):
        assert needs_network(ClusterConfig(method=method), discrete) is neural


def test_bc_auto_keeps_cpu_only_settings_on_the_cpu():
    from pcpg_dist.stages.bc import bc_device, runs_on_cpu_only

    assert runs_on_cpu_only(BCConfig(batch_size=32)) and runs_on_cpu_only(BCConfig(engine="numba"))
    assert not runs_on_cpu_only(BCConfig())
    assert bc_device(BCConfig(device="auto", batch_size=32)).type == "cpu"


@pytest.mark.skipif(__import__("torch").cuda.is_available(), reason="the local Ray here has no GPU")
def test_run_on_cuda_without_a_gpu_is_refused_before_anything_starts(ray_session, tmp_path):
    import yaml
    from test_runner import TINY

    from pcpg_dist.api.run import run_experiment
    from pcpg_dist.config import load_config

    path = tmp_path / "tiny.yaml"
    path.write_text(
        yaml.safe_dump(
            {**TINY, "clustering": {**TINY["clustering"], "method": "lstm_dec", "device": "cuda"}}
        )
    )
    with pytest.raises(ConfigError, match="^clustering.device is 'cuda' but no Ray node has a GPU"):
        run_experiment(
            load_config(path), workdir=tmp_path / "runs", track=False, show_progress=False
        )
    assert not (tmp_path / "runs").exists()
