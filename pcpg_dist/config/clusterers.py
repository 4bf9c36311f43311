"""The table of Step A's clusterers: every method name, where its fitting code lives and what it can
do, in one place (pure data: reading it imports no stage and no torch).

Everything that asks what a clustering method is derives from :data:`CLUSTERERS`: the names
``clustering.method`` accepts (and their order in its error message), which methods give Step B a
likelihood, which may ask Ray for a GPU, how :func:`pcpg_dist.stages.clustering.cluster` dispatches
and how a saved model is read back. A new method is one new row here plus its fitting function.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

#: what a saved cluster model holds beside mean, std and centroids (it fixes how it is read back):
#: an LSTM autoencoder, normalised summaries, a visited-state vocabulary, a visitation bag, a bag
#: plus a mixture of greedy policies, a mixture of neural policies, or a mixture of choice models
#: over the game's move features
ModelKind = Literal["autoencoder", "summary", "visits", "bag", "greedy", "policy", "choice"]


@dataclass(frozen=True)
class Clusterer:
    """One clustering method: its fitting function and its properties."""

    #: the fitting function as a lazy ``"module:function"`` target, imported only when it runs
    fit: str
    #: what its saved model holds (:data:`ModelKind`)
    model: ModelKind
    #: scores every trajectory against every cluster, so Step B's ``ranking.style_margin`` works
    likelihood: bool = False
    #: trains a neural network itself (so it uses ``clustering.device`` and may ask for a GPU)
    trains_network: bool = False
    #: refuses a dataset whose states are continuous (most state rows occur once)
    discrete_states_only: bool = False
    #: the method it hands a dataset of continuous states to instead (None: it fits them itself)
    continuous_fallback: str | None = None


_BAGS = "pcpg_dist.stages.clustering.bags:fit_bags"
_LSTM = "pcpg_dist.stages.clustering.lstm:fit_lstm"

#: every clustering method, in the order ``clustering.method``'s error message lists them
CLUSTERERS: dict[str, Clusterer] = {
    "lstm_dec": Clusterer(_LSTM, "autoencoder", trains_network=True),
    "lstm_kmeans": Clusterer(_LSTM, "autoencoder", trains_network=True),
    "summary_kmeans": Clusterer("pcpg_dist.stages.clustering.kmeans:fit_summary", "summary"),
    "visits_kmeans": Clusterer("pcpg_dist.stages.clustering.kmeans:fit_visits", "visits"),
    "bag_kmeans": Clusterer(_BAGS, "bag"),
    "bag_mop": Clusterer(_BAGS, "bag"),
    "greedy_mix": Clusterer(_BAGS, "greedy", likelihood=True, discrete_states_only=True),
    "bag_auto": Clusterer(_BAGS, "greedy", likelihood=True, continuous_fallback="policy_mix"),
    "policy_mix": Clusterer(
        "pcpg_dist.stages.clustering.policy_mix:fit_policy_mix",
        "policy",
        likelihood=True,
        trains_network=True,
    ),
    "choice_mix": Clusterer(
        "pcpg_dist.stages.clustering.move_features:fit_choice", "choice", likelihood=True
    ),
}

#: the names ``clustering.method`` accepts
METHOD_NAMES: tuple[str, ...] = tuple(CLUSTERERS)

#: the type of ``clustering.method``: one of :data:`METHOD_NAMES`
ClusterMethod = Literal[METHOD_NAMES]  # type: ignore[valid-type]

#: the clusterers that score each trajectory against every cluster (``ranking.style_margin``)
LIKELIHOOD_METHODS: tuple[str, ...] = tuple(n for n, c in CLUSTERERS.items() if c.likelihood)


def may_train_network(method: str) -> bool:
    """Whether ``method`` may train a network: itself, or through its continuous-state fallback."""
    spec = CLUSTERERS[method]
    fallback = spec.continuous_fallback
    return spec.trains_network or (fallback is not None and CLUSTERERS[fallback].trains_network)


NEURAL_CLUSTERERS = frozenset(n for n in CLUSTERERS if may_train_network(n))
"""Clustering methods that may train a network (``bag_auto`` falls back to ``policy_mix`` on
continuous states): only these use ``clustering.device`` and ask Ray for a GPU."""

#: methods whose saved model reads trajectories as visitation bags (nearest mean in bag space)
BAG_METHODS: tuple[str, ...] = tuple(
    n for n, c in CLUSTERERS.items() if c.model in ("bag", "greedy")
)
#: bag methods whose saved model is a mixture of greedy policies
GREEDY_METHODS: tuple[str, ...] = tuple(n for n, c in CLUSTERERS.items() if c.model == "greedy")
