"""``bag_auto``'s choice, without labels, of the fit the data supports best.

On discrete states: greedy_mix (one greedy action per exact state) is at the supervised ceiling
on GridWorld-shaped logs, where states repeat and each style holds one action in each; on
discrete logs where they do not (an egocentric view, a card game's information states) its fit
wanders with the sample while a mixture of neural policies, which generalises across states,
comes back the same. On continuous states policy_mix alone runs, as its fallback.

Then policy_mix whose policies also see the time step (``policy_time``): styles that act by
schedule (mountaincar's rocking back up the left slope for its first 15-34 steps, then pumping)
are not Markov in the state, so policies of the state alone mix them; given log(1 + t), and
with t among the counters of its start, they come apart (docs/zoo.md, "Policies that see the
time step").

The candidates are fitted in that order, each refitted ``clustering.confidence_runs`` times on
subsamples (the label-free confidence, :mod:`.confidence`); a later one replaces the one kept so
far only where its stability is higher by more than :data:`MARGIN`, or where it fills all k clusters and
the kept one does not (:func:`better`). Once the kept fit fills them and its stability
is ``1 - MARGIN`` or more nothing can beat it, so no further candidate is fitted (every GridWorld
layout, cartpole, freeway, mujoco_pendulum: the choice costs nothing there). With
``confidence_runs: 0`` nothing is refitted and the first candidate runs alone, as before.

policy_mix with the time step, kept by that rule while its own fit does not read "styles found",
gives way to policy_mix without it (:func:`stand_in`).

The kept clustering's stability is its confidence (kept in its metrics, not measured again);
having been picked as the most stable, it leans optimistic by the selection.
"""

from __future__ import annotations

import dataclasses
import time

from pcpg_dist.config.clusterers import CLUSTERERS
from pcpg_dist.stages.clustering.auto import chooses, fallback_for, falls_back
from pcpg_dist.stages.clustering.confidence import FOUND, stability
from pcpg_dist.stages.clustering.step import Clustering, cluster_once

#: a candidate replaces the fit kept so far only where its stability is higher by more than
#: this: on the design logs policy_mix's exceeds greedy_mix's by at most 0.01 where greedy_mix is
#: as good or better (GridWorld E1-E5) and by 0.28-0.32 where policy_mix is better
#: (minigrid_empty, leduc_poker); two refits move a stability by a few hundredths
MARGIN = 0.10
TIMED = "policy_mix_time"  # the name of policy_mix with ``policy_time`` among the candidates


def candidates(dataset, cfg) -> list[tuple[str, object]]:
    """``(name, config)`` of each fit bag_auto may keep, in the order they are tried."""
    if falls_back(dataset):  # bag_auto itself hands the data to policy_mix (and says so)
        if fallback_for(cfg.method, dataset) != "policy_mix":
            return []  # lstm_dec: only the states can show a style, nothing to choose
        return [
            ("policy_mix", cfg.model_copy(update={"policy_time": False})),
            (TIMED, cfg.model_copy(update={"policy_time": True})),
        ]
    policy = cfg.model_copy(update={"method": "policy_mix"})
    return [
        ("greedy_mix", cfg.model_copy(update={"method": "greedy_mix"})),
        ("policy_mix", policy.model_copy(update={"policy_time": False})),
        (TIMED, policy.model_copy(update={"policy_time": True})),
    ]


def cluster(dataset, cfg, seed: int) -> Clustering:
    """Cluster ``dataset``'s trajectories into ``cfg.k`` play-styles; never reads ``dataset.styles``.

    ``bag_auto`` chooses among :func:`candidates` (module doc); every other method, and
    ``confidence_runs: 0``, is one fit (:func:`.step.cluster_once`).
    Raises :class:`DataError` for an empty dataset, non-finite states, or fewer trajectories than k.
    Call :func:`pcpg_dist.common.devices.set_threads` first: same data + seed + threads = same labels.
    """
    tried = candidates(dataset, cfg) if chooses(cfg) else []
    if not tried and cfg.restarts > 1 and cfg.confidence_runs > 0 and cfg.k > 1:
        tried = [(cfg.method, cfg)]  # one method, restarted: keep its most stable fit
    if not tried:
        return cluster_once(dataset, cfg, seed)
    return most_stable(dataset, cfg, seed, tried)


def clusters_used(result: Clustering, k: int) -> float:
    """How many of the k clusters hold a trajectory."""
    return result.metrics.get("n_clusters_used", k)


def filled(result: Clustering, k: int) -> bool:
    """Whether every one of the k clusters holds a trajectory."""
    return clusters_used(result, k) >= k


def settled(result: Clustering, stable: float, k: int) -> bool:
    """Whether no other fit can beat ``result`` (:func:`better`): it fills all k clusters and
    its stability is ``1 - MARGIN`` or more, so no further fit is tried."""
    return filled(result, k) and stable + MARGIN >= 1.0


def better(
    result: Clustering,
    stable: float,
    kept: Clustering,
    kept_stable: float,
    k: int,
    margin: float = MARGIN,
) -> bool:
    """Whether a candidate's fit replaces the one kept so far: it fills all k clusters where the
    kept one does not, or both fill as many and its stability is higher by more than ``margin``.

    A fit that leaves clusters empty has no measurable stability: two refits that put every
    trajectory in one cluster agree perfectly (ARI 1), so on tictactoe greedy_mix's collapse to
    one cluster (0.444) read as stability 1.00 and stopped the search before policy_mix (0.58),
    on the eighth session's machine (on the seventh's, same code, its refits had split). The
    collapse still counts as evidence of fewer styles: the verdict says "no evidence of k
    styles", however stable the kept fit (:func:`.confidence.collapsed_candidate`)."""
    if filled(result, k) != filled(kept, k):
        return filled(result, k)
    return stable > kept_stable + margin


#: restart r of a fit uses seed + RESTART_SEEDS * r (its refits use the seeds after its own)
RESTART_SEEDS = 1000


def restartable(one, dataset, fell: bool) -> bool:
    """Whether restarts can change candidate ``one``'s fit: a network's training depends on its
    seed. The bag and greedy methods already search from many seeded starts within one fit
    (greedy_mix: k-means starts of k to k + 2 clusters, then split and merge), so a restart would
    only redraw their refits' subsamples, and keeping the highest of those stabilities is a
    winner's curse: on leduc_poker, restarting greedy_mix too kept its 0.585 at stability 0.91
    over policy_mix's 0.757 (docs/zoo.md, "Restarts"). ``fell``: :func:`.auto.falls_back`."""
    method = one.method
    if fell:
        method = fallback_for(method, dataset) or method
    return CLUSTERERS[method].trains_network


def best_restart(dataset, one, cfg, seed: int, fell: bool) -> tuple[Clustering, dict, int]:
    """(clustering, its stability metrics, restart index): the most stable of ``cfg.restarts``
    fits of one candidate ``one`` (one fit where it is not :func:`restartable`), each with its
    ``confidence_runs`` refits; the restarts stop once a fit fills all k clusters with stability
    ``1 - MARGIN`` or more."""
    kept = None
    for r in range(cfg.restarts if restartable(one, dataset, fell) else 1):
        at = seed + RESTART_SEEDS * r
        result = cluster_once(dataset, one, at)
        found = stability(
            dataset, one, at, result.labels, cfg.confidence_runs, cfg.confidence_fraction
        )
        stable = found["stability"]
        if kept is None or better(result, stable, kept[0], kept[1]["stability"], cfg.k, 0.0):
            kept = (result, found, r)
        if settled(kept[0], kept[1]["stability"], cfg.k):
            break
    return kept


def stand_in(kept: str, fits: dict, k: int) -> str:
    """The candidate whose fit is used: ``kept``, except where that is policy_mix with the time step
    and its fit does not read "styles found" (stability below :data:`.confidence.FOUND`): then
    policy_mix without it, already fitted, if that fills all k clusters. The time step is an input
    more, so its fit can follow more of the sample; picked for a stability that is low anyway, it
    is a winner's curse (as restarts of greedy_mix were): on the design games tictactoe (seeds 0
    and 2: stabilities 0.53 and 0.56, accuracies 0.693 and 0.656 against 0.747 and 0.722 without
    it) and minigrid_empty (seed 0: 0.75, 0.633 against 0.663). Where the styles do act by
    schedule its fit is confident (mountaincar: 0.98-1.00) and is kept."""
    plain = fits.get("policy_mix")
    if kept == TIMED and fits[kept][1]["stability"] < FOUND and plain and filled(plain[0], k):
        return "policy_mix"
    return kept


def most_stable(dataset, cfg, seed: int, tried: list[tuple[str, object]]) -> Clustering:
    """The clustering of the candidate kept by the module doc's rule, with every fitted
    candidate's stability and the choice in its metrics; its ``fit_seconds`` are those of every
    fit and refit."""
    start = time.perf_counter()
    fits, kept = {}, None  # name -> (clustering, its stability metrics, restart index)
    fell = cfg.restarts > 1 and falls_back(dataset)  # restartable() reads it: computed once
    for name, one in tried:
        if kept is not None and settled(fits[kept][0], fits[kept][1]["stability"], cfg.k):
            break  # no stability can beat it by MARGIN: GridWorld
        fits[name] = result, found, _ = best_restart(dataset, one, cfg, seed, fell)
        if kept is None or better(
            result, found["stability"], fits[kept][0], fits[kept][1]["stability"], cfg.k
        ):
            kept = name
    chosen = stand_in(kept, fits, cfg.k)
    result, found, restart = fits[chosen]
    metrics = {
        **result.metrics,
        **found,
        **({"restart_kept": float(restart)} if cfg.restarts > 1 else {}),
        **{f"auto_stability_{m}": f[1]["stability"] for m, f in fits.items()},
        **{f"auto_clusters_used_{m}": clusters_used(f[0], cfg.k) for m, f in fits.items()},
        "auto_chose_policy_mix": float(chosen != "greedy_mix" and "greedy_mix" in fits),
        "auto_chose_policy_time": float(chosen == TIMED),
        "auto_time_set_aside": float(chosen != kept),
    }
    return dataclasses.replace(result, metrics=metrics, fit_seconds=time.perf_counter() - start)
