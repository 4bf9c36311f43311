"""What a stage's tasks ask Ray for: a GPU share where a stage trains a network on a GPU."""

from __future__ import annotations

from pcpg_dist.config import ExperimentConfig


def cluster_gpus(cfg: ExperimentConfig, node_gpus: float) -> float:
    """GPUs a clustering task of ``cfg`` asks Ray for (none unless a neural method is on a GPU);
    ``node_gpus``: the most one live node has (:func:`pcpg_dist.orchestration.ray_pool.node_gpus`)."""
    from pcpg_dist.common.devices import stage_gpus
    from pcpg_dist.config.stages import NEURAL_CLUSTERERS

    if cfg.clustering.device == "cpu" or cfg.clustering.method not in NEURAL_CLUSTERERS:
        return 0.0
    return stage_gpus(
        cfg.clustering.device, cfg.runner.gpus_per_task, node_gpus, "clustering.device"
    )


def trains_a_network(cluster_cfg, dataset) -> bool:
    """Whether Step A trains a network on ``dataset`` (a unit's clustering input): ``bag_auto``
    does only on continuous states (its fallback), so on discrete ones its task needs no GPU."""
    from pcpg_dist.config.stages import NEURAL_CLUSTERERS

    if cluster_cfg.method != "bag_auto":
        return cluster_cfg.method in NEURAL_CLUSTERERS
    from pcpg_dist.stages.clustering.cluster import falls_back_to_lstm

    return falls_back_to_lstm(dataset)


def unit_cluster_gpus(share: float, cluster_cfg, dataset) -> float:
    """What one unit's clustering task asks for: the stage's ``share`` where it trains a network."""
    return share if share and trains_a_network(cluster_cfg, dataset) else 0.0


def bc_gpus(cfg: ExperimentConfig, node_gpus: float) -> float:
    """GPUs a BC training task of ``cfg`` asks Ray for (``node_gpus`` as in :func:`cluster_gpus`)."""
    from pcpg_dist.common.devices import stage_gpus
    from pcpg_dist.stages.bc import runs_on_cpu_only

    if cfg.bc.device == "cpu" or (cfg.bc.device == "auto" and runs_on_cpu_only(cfg.bc)):
        return 0.0
    return stage_gpus(cfg.bc.device, cfg.runner.gpus_per_task, node_gpus, "bc.device")


# --------------------------------------------------------------------------- the run
