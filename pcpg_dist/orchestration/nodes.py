"""What the Ray cluster has (CPUs, GPUs and memory per live node) and keeping a task on the
driver's node, for work on files only that node holds."""

from __future__ import annotations


def node_capacities() -> list[dict[str, float]]:
    """CPUs, GPUs and task memory (bytes) of every live node."""
    import ray

    keys = ("CPU", "GPU", "memory")
    return [
        {k: float(n["Resources"].get(k, 0)) for k in keys} for n in ray.nodes() if n.get("Alive")
    ]


def node_gpus() -> float:
    """The most GPUs one live node offers (0 on a cluster without GPUs)."""
    return max((n["GPU"] for n in node_capacities()), default=0.0)


def on_driver_node() -> dict | None:
    """Ray options that keep a task on the driver's node where the cluster has others (None on
    one node): for work on files only that node has (a local log's row groups, the run folder an
    MLflow child run is logged from). A driver's node with no CPU of its own (a head started with
    --num-cpus=0) runs them asking for none."""
    import ray
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    nodes = [n for n in ray.nodes() if n.get("Alive")]
    if len(nodes) < 2:
        return None
    here = ray.get_runtime_context().get_node_id()
    cpus = next((n["Resources"].get("CPU", 0.0) for n in nodes if n["NodeID"] == here), 0.0)
    options = {"scheduling_strategy": NodeAffinitySchedulingStrategy(here, soft=False)}
    return options if cpus >= 1 else {**options, "num_cpus": 0}
