"""A label-free confidence in a clustering: how much a user without labels may trust that the k
clusters are k play-styles, and a verdict in plain words.

The evidence is **stability under resampling**: the same method is fitted again, with other
seeds, on random subsamples of the trajectories (``runs`` x ``fraction`` of them), and each refit
is compared with the clustering on the trajectories they share:

- ``stability``: the mean adjusted Rand index between the clustering and the refits (1: the same
  partition every time; about 0: no more alike than chance). Clusters that follow real styles
  come back when the data is resampled; clusters cut through noise, or a search that lands in a
  different optimum every time, do not.
- ``merged_pairs``: pairs of clusters whose trajectories the refits mostly put together (their
  distributions over the refit's clusters overlap by more than half): two clusters that look like
  one style.
- the clusterer's own fall-back (``bag_auto`` handing continuous states to ``policy_mix``) is said,
  and so is its choice of policy_mix on discrete states (:mod:`.select`: there the stability is
  the larger of two, so it leans optimistic).

A clustering that leaves clusters empty (a collapse is stable, and says there are fewer styles)
is "no evidence of k styles" whatever its stability. Otherwise the verdict reads ``stability``
against two thresholds (:data:`FOUND`, :data:`WEAK`): "styles found", "weak evidence" or "no
evidence of k styles". FOUND sits in the middle of the interval that separates, on the zoo's
design games and GridWorld's E1-E5, the clusterings within 5 points of the honest ceiling
(stability 0.91 and up) from those farther (0.82 and below); the held-out games were checked
after (docs/zoo.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: stability at or above which the verdict is "styles found"; at or above WEAK, "weak evidence"
FOUND = 0.85
WEAK = 0.50
MERGED = 0.5  # overlap of two clusters' refit distributions above which they look like one style


def stability(dataset, cfg, seed: int, labels: np.ndarray, runs: int, fraction: float) -> dict:
    """Refit ``cfg``'s method ``runs`` times on seeded subsamples; the metrics of the module doc."""
    from sklearn.metrics import adjusted_rand_score  # here: a run's driver reads verdicts only

    from pcpg_dist.stages.clustering.step import cluster_once as cluster

    labels = np.asarray(labels)
    n, k = len(labels), cfg.k
    cfg = cfg.model_copy(update={"confidence_runs": 0})  # a refit is one fit, never a choice
    rng = np.random.default_rng([seed, 7919])
    size = max(k, int(round(fraction * n)))
    aris, overlaps = [], np.zeros((k, k))
    for r in range(runs):
        idx = np.sort(rng.choice(n, size=size, replace=False))
        refit = np.asarray(cluster(dataset.subset(idx), cfg, seed + 1 + r).labels)
        ref = labels[idx]
        aris.append(adjusted_rand_score(ref, refit))
        overlaps += _overlap(ref, refit, k)
    overlaps /= max(runs, 1)
    merged = [(a, b) for a in range(k) for b in range(a + 1, k) if overlaps[a, b] > MERGED]
    return {
        "stability": float(np.mean(aris)),
        "stability_min": float(np.min(aris)),
        "stability_runs": float(runs),
        "stability_k": float(k),
        "merged_pairs": float(len(merged)),
        **{f"merged_pair_{a}_{b}": float(overlaps[a, b]) for a, b in merged},
    }


def _overlap(ref: np.ndarray, refit: np.ndarray, k: int) -> np.ndarray:
    """(k, k): for clusters a, b of ``ref``, sum over refit clusters c of min(P(c|a), P(c|b))."""
    kk = max(k, int(refit.max(initial=0)) + 1)
    table = np.zeros((k, kk))
    np.add.at(table, (ref, refit), 1.0)
    sizes = table.sum(axis=1, keepdims=True)
    dist = np.divide(table, sizes, out=np.zeros_like(table), where=sizes > 0)
    out = np.minimum(dist[:, None, :], dist[None, :, :]).sum(axis=2)
    out[sizes[:, 0] == 0, :] = 0.0
    out[:, sizes[:, 0] == 0] = 0.0
    return out


@dataclass(frozen=True)
class Verdict:
    """The confidence in words: a verdict and the warnings that go with it."""

    verdict: str  # "styles found", "weak evidence", "no evidence of k styles", "not measured"
    reasons: tuple[str, ...]

    def line(self) -> str:
        return self.verdict + (f" ({'; '.join(self.reasons)})" if self.reasons else "")

    @property
    def doubts_styles(self) -> bool:
        """Weak or no evidence: the clusters may not be styles (``bc.init: auto`` then starts
        the per-cluster agents from No Clustering)."""
        return self.verdict.startswith(("weak evidence", "no evidence"))


def collapsed_candidate(metrics: dict, k: int | None) -> tuple[str, float] | None:
    """(name, clusters used) of a candidate that ``bag_auto`` fitted and did not keep because it
    left clusters empty (``auto_clusters_used_<name>`` below k), or None. A collapse says the log
    may hold fewer styles than k, and the kept fit that fills all k does not overrule it, however
    stable (:func:`verdict_of`): a fit can cut one style the same way every time (by how noisy
    each player is, on the one-style toy of tests/stages/test_confidence.py: stability 0.93 with
    the consensus start), and stability cannot tell such a cut from styles (Ben-David, von
    Luxburg and Pal, 2006)."""
    for key, v in metrics.items():
        name = key.removeprefix("clustering/")
        if k and name.startswith("auto_clusters_used_") and float(v) < k:
            return name.removeprefix("auto_clusters_used_"), float(v)
    return None


def verdict_of(metrics: dict, k: int | None = None) -> Verdict:
    """The verdict from a unit's clustering metrics (``clustering/…`` keys or bare ones)."""

    def get(name: str) -> float | None:
        v = metrics.get(f"clustering/{name}", metrics.get(name))
        return None if v is None else float(v)

    reasons = []
    if get("auto_chose_choice_mix"):
        reasons.append("bag_auto clustered by the moves' features (choice_mix)")
    if get("auto_fell_back"):
        to = "lstm_dec" if get("auto_fell_back_to_lstm") else "policy_mix"
        reasons.append(f"bag_auto fell back to {to} (continuous states)")
    if get("auto_chose_policy_time"):
        t, p = get("auto_stability_policy_mix_time"), get("auto_stability_policy_mix")
        reasons.append(
            f"bag_auto chose policy_mix with the time step (stability {t:.2f}; without {p:.2f})"
        )
    elif get("auto_time_set_aside"):
        t, p = get("auto_stability_policy_mix_time"), get("auto_stability_policy_mix")
        reasons.append(
            f"bag_auto kept policy_mix without the time step (stability {p:.2f}): with it, "
            f"{t:.2f}, more stable but below {FOUND:.2f}"
        )
    elif get("auto_chose_policy_mix"):
        g, p = get("auto_stability_greedy_mix"), get("auto_stability_policy_mix")
        reasons.append(f"bag_auto chose policy_mix (stability {p:.2f}; greedy_mix {g:.2f})")
    merged = [
        key.rsplit("merged_pair_", 1)[1].replace("_", " and ")
        for key in metrics
        if "merged_pair_" in key
    ]
    if merged:
        reasons.append("clusters " + ", ".join(merged) + " look like one style")
    s = get("stability")
    if s is None:
        return Verdict("not measured", tuple(reasons))
    reasons.insert(0, f"stability {s:.2f}")
    k = k or (int(get("stability_k")) if get("stability_k") else None)
    used = get("n_clusters_used")
    if k and used is not None and used < k:  # a collapse is stable, and says fewer styles
        reasons.insert(1, f"only {used:.0f} of {k} clusters hold trajectories")
        return Verdict(f"no evidence of {k} styles", tuple(reasons))
    collapsed = collapsed_candidate(metrics, k)
    if collapsed:  # no stability overrules another candidate's collapse
        name, n = collapsed
        reasons.insert(1, f"in {name}'s fit only {n:.0f} of {k} clusters hold trajectories")
        return Verdict(f"no evidence of {k} styles", tuple(reasons))
    if s >= FOUND:
        word = "styles found"
    elif s >= WEAK:
        word = "weak evidence"
    else:
        word = f"no evidence of {k if k else 'k'} styles"
    return Verdict(word, tuple(reasons))
