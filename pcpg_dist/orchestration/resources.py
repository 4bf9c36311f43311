"""What a stage's tasks ask Ray for: a GPU share where a stage trains a network on a GPU."""

from __future__ import annotations

from pcpg_dist.config import ExperimentConfig
from pcpg_dist.stages.clustering.auto import needs_network


def cluster_gpus(cfg: ExperimentConfig, node_gpus: float) -> float:
    """GPUs a clustering task of ``cfg`` asks Ray for (none unless a neural method is on a GPU);
    ``node_gpus``: the most one live node has (:func:`pcpg_dist.orchestration.nodes.node_gpus`)."""
    from pcpg_dist.common.devices import stage_gpus
    from pcpg_dist.config.clusterers import NEURAL_CLUSTERERS

    if cfg.clustering.device == "cpu" or cfg.clustering.method not in NEURAL_CLUSTERERS:
        return 0.0
    return stage_gpus(
        cfg.clustering.device, cfg.runner.gpus_per_task, node_gpus, "clustering.device"
    )


def unit_cluster_gpus(share: float, cluster_cfg, dataset) -> float:
    """What one unit's clustering task asks for: the stage's ``share`` where it trains a network."""
    return share if share and needs_network(cluster_cfg, dataset) else 0.0


def bc_gpus(cfg: ExperimentConfig, node_gpus: float) -> float:
    """GPUs a BC training task of ``cfg`` asks Ray for (``node_gpus`` as in :func:`cluster_gpus`)."""
    from pcpg_dist.common.devices import stage_gpus
    from pcpg_dist.stages.bc import runs_on_cpu_only

    if cfg.bc.device == "cpu" or (cfg.bc.device == "auto" and runs_on_cpu_only(cfg.bc)):
        return 0.0
    return stage_gpus(cfg.bc.device, cfg.runner.gpus_per_task, node_gpus, "bc.device")


# --------------------------------------------------------------------------- the run
