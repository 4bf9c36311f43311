"""``bag_auto`` on discrete states: greedy_mix or policy_mix, whichever the data supports better,
chosen without labels.

greedy_mix (one greedy action per exact state) is at the supervised ceiling on GridWorld-shaped
logs, where states repeat and each style holds one action in each; on discrete logs where they
do not (an egocentric view, a card game's information states) its fit wanders with the sample
while a mixture of neural policies, which generalises across states, comes back the same. Both are
fitted, each is refitted ``clustering.confidence_runs`` times on subsamples (the label-free
confidence, :mod:`.confidence`), and the clustering whose refits agree with it more is kept:
policy_mix only where its stability is higher by more than :data:`MARGIN`, greedy_mix otherwise
(docs/zoo.md, "Choosing between greedy_mix and policy_mix"). Where greedy_mix's stability is
``1 - MARGIN`` or more no stability can beat it, so policy_mix is not fitted (every GridWorld
layout measured: the choice costs nothing there). With ``confidence_runs: 0`` nothing is
refitted and greedy_mix runs alone, as before.

The chosen clustering's stability is its confidence (kept in its metrics, not measured again);
having been picked as the more stable of two, it leans optimistic by the selection.
"""

from __future__ import annotations

import dataclasses
import time

from pcpg_dist.stages.clustering.auto import chooses, falls_back
from pcpg_dist.stages.clustering.confidence import stability
from pcpg_dist.stages.clustering.step import Clustering, cluster_once

#: policy_mix replaces greedy_mix only where its stability is higher by more than this: on the
#: design logs policy_mix's exceeds greedy_mix's by at most 0.01 where greedy_mix is as good or
#: better (GridWorld E1-E5) and by 0.28-0.32 where policy_mix is better (minigrid_empty,
#: leduc_poker); two refits move a stability by a few hundredths
MARGIN = 0.10
CANDIDATES = ("greedy_mix", "policy_mix")


def cluster(dataset, cfg, seed: int) -> Clustering:
    """Cluster ``dataset``'s trajectories into ``cfg.k`` play-styles; never reads ``dataset.styles``.

    ``bag_auto`` on discrete states chooses between greedy_mix and policy_mix (module doc); every
    other method, and bag_auto on continuous states, is one fit (:func:`.step.cluster_once`).
    Raises :class:`DataError` for an empty dataset, non-finite states, or fewer trajectories than k.
    Call :func:`pcpg_dist.common.devices.set_threads` first: same data + seed + threads = same labels.
    """
    if chooses(cfg) and not falls_back(dataset):
        return most_stable(dataset, cfg, seed)
    return cluster_once(dataset, cfg, seed)


def most_stable(dataset, cfg, seed: int) -> Clustering:
    """The clustering of the candidate with the more stable fit (module doc), with both
    stabilities and the choice in its metrics; its ``fit_seconds`` are those of both fits and
    their refits."""
    start = time.perf_counter()
    fits = {}
    for method in CANDIDATES:
        one = cfg.model_copy(update={"method": method})
        result = cluster_once(dataset, one, seed)
        found = stability(
            dataset, one, seed, result.labels, cfg.confidence_runs, cfg.confidence_fraction
        )
        fits[method] = (result, found)
        if found["stability"] + MARGIN >= 1.0:  # no stability can beat it by MARGIN: GridWorld
            break
    stable = {m: found["stability"] for m, (_, found) in fits.items()}
    greedy, policy = stable["greedy_mix"], stable.get("policy_mix", -1.0)
    chosen = "policy_mix" if policy > greedy + MARGIN else "greedy_mix"
    result, found = fits[chosen]
    metrics = {
        **result.metrics,
        **found,
        "auto_chose_policy_mix": float(chosen == "policy_mix"),
        **{f"auto_stability_{m}": v for m, v in stable.items()},
    }
    return dataclasses.replace(result, metrics=metrics, fit_seconds=time.perf_counter() - start)
