"""Which clusterer actually runs on a dataset, and whether it trains a network there.

A method of :data:`pcpg_dist.config.clusterers.CLUSTERERS` may refuse continuous states
(``greedy_mix``: a per-state policy cannot be estimated where every state is new) or hand them to
another method (``bag_auto`` falls back to ``policy_mix``, or to ``lstm_dec`` where every step
logs the same action, so only the states can show a style). States count as continuous where most
state rows are distinct. Numpy only, so the runner can ask before it asks Ray for a GPU.
"""

from __future__ import annotations

from pcpg_dist.common.errors import DataError
from pcpg_dist.config.clusterers import CLUSTERERS
from pcpg_dist.config.clustering import ClusterConfig
from pcpg_dist.stages.clustering.states import checked_sequences, mostly_distinct_states


def falls_back(dataset) -> bool:
    """Whether ``bag_auto`` clusters ``dataset`` with its continuous-state fallback (policy_mix)
    rather than greedy_mix: most of its states occur once."""
    return mostly_distinct_states(checked_sequences(dataset)[0])


def fallback_for(method: str, dataset) -> str | None:
    """The method ``method`` hands ``dataset`` to where its states are continuous: its table
    entry's fallback, or ``lstm_dec`` where the log's actions say nothing (one action throughout:
    a mixture of policies would see no style, a sequence model of the states still can)."""
    fallback = CLUSTERERS[method].continuous_fallback
    if fallback is None or not CLUSTERERS[fallback].likelihood:
        return fallback
    acts = dataset.actions[dataset.actions >= 0]
    return "lstm_dec" if acts.size and (acts == acts[0]).all() else fallback


def chooses(cfg: ClusterConfig) -> bool:
    """Whether ``cfg`` has ``bag_auto`` choose its fit by stability (greedy_mix, policy_mix,
    policy_mix seeing the time step: :mod:`.select`; ``clustering.confidence_runs`` refits each)."""
    if cfg.move_features is not None:
        return False  # choice_mix is the fit (by_moves)
    return cfg.method == "bag_auto" and cfg.confidence_runs > 0 and cfg.k > 1


def by_moves(cfg: ClusterConfig) -> bool:
    """Whether ``bag_auto`` hands the log to ``choice_mix``: the user gave its move features."""
    return cfg.method == "bag_auto" and cfg.move_features is not None


def needs_network(cluster_cfg: ClusterConfig, dataset) -> bool:
    """Whether Step A trains a network on ``dataset`` (a unit's clustering input): a method with a
    continuous-state fallback (``bag_auto``) trains one where it falls back to a method that does,
    or where it may choose policy_mix on discrete states (``confidence_runs`` > 0)."""
    spec = CLUSTERERS[cluster_cfg.method]
    if by_moves(cluster_cfg):
        return False
    if spec.continuous_fallback is not None:
        if falls_back(dataset):
            return CLUSTERERS[fallback_for(cluster_cfg.method, dataset)].trains_network
        # on discrete states it may fit policy_mix beside greedy_mix to choose (select.py)
        return spec.trains_network or chooses(cluster_cfg)
    return spec.trains_network


def resolve_method(cfg: ClusterConfig, dataset, states, metrics: dict[str, float]) -> ClusterConfig:
    """``cfg`` with the method that runs on ``states``: refused where the method needs discrete
    states and they are continuous, switched to its fallback where it has one (noted in
    ``metrics``)."""
    if by_moves(cfg):
        metrics["auto_chose_choice_mix"] = 1.0
        return cfg.model_copy(update={"method": "choice_mix"})
    spec = CLUSTERERS[cfg.method]
    if spec.discrete_states_only and mostly_distinct_states(states):
        raise DataError(
            f"clustering.method {cfg.method}: most states of {dataset.domain}-{dataset.env} "
            "occur once (continuous states), so a per-state policy cannot be estimated; "
            "use bag_auto, policy_mix or lstm_dec"
        )
    if spec.continuous_fallback is not None and mostly_distinct_states(states):
        # Continuous states: every state is new, a visitation bag says nothing; a mixture of
        # neural policies still sees which action each style takes where (docs/zoo.md: better
        # than lstm_dec on 5 of the 7 design games that fall back, never worse on the held-out)
        fallback = fallback_for(cfg.method, dataset)
        cfg = cfg.model_copy(update={"method": fallback})
        metrics["auto_fell_back"] = 1.0
        metrics["auto_fell_back_to_lstm"] = float(fallback == "lstm_dec")
    return cfg
