"""The label-free confidence (pcpg_dist/stages/clustering/confidence.py) on small real problems:
clear styles are stable and found; one style cut into clusters is unstable and said to be no
evidence; a style split in two is flagged as two clusters that look like one style."""

from __future__ import annotations

import numpy as np
from bc_toy import make_dataset

from pcpg_dist.config.clustering import ClusterConfig
from pcpg_dist.stages.clustering import cluster
from pcpg_dist.stages.clustering.confidence import FOUND, stability, verdict_of


def test_clear_styles_are_stable_and_found():
    ds = make_dataset(n_per_style=60, styles=2)
    cfg = ClusterConfig(k=2)
    labels = cluster(ds, cfg, 0).labels
    found = stability(ds, cfg, 0, labels, runs=2, fraction=0.8)
    assert found["stability"] >= FOUND and found["merged_pairs"] == 0
    said = verdict_of(found, 2)
    assert said.verdict == "styles found" and said.reasons[0].startswith("stability ")
    again = stability(ds, cfg, 0, labels, runs=2, fraction=0.8)
    assert again == found  # the same seed gives the same numbers


def test_one_style_cut_into_clusters_is_no_evidence():
    ds = make_dataset(n_per_style=120, styles=1)
    cfg = ClusterConfig(k=3)
    result = cluster(ds, cfg, 0)
    found = stability(ds, cfg, 0, result.labels, runs=2, fraction=0.8)
    # greedy_mix puts one style in one cluster, every time: stable, and no evidence of 3 styles
    said = verdict_of({**result.metrics, **found})
    assert said.verdict == "no evidence of 3 styles", said
    assert "clusters hold trajectories" in said.reasons[1]
    # bag_auto's own confidence: a fit that fills the 3 clusters may be kept for its labels
    # (select.better), but it does not overrule greedy_mix's collapse, however stable: the
    # consensus start cuts this one style by how noisy each trajectory is, the same way on
    # every subsample (stability 0.93 here)
    own = verdict_of(result.metrics)
    assert own.verdict == "no evidence of 3 styles", own
    assert "clusters hold trajectories" in own.reasons[1]
    if result.metrics["n_clusters_used"] == 3:
        assert result.metrics["auto_clusters_used_greedy_mix"] < 3
    # k-means must cut it into 3: where the cuts fall moves with the sample
    cut = ClusterConfig(k=3, method="summary_kmeans")
    result = cluster(ds, cut, 0)
    found = stability(ds, cut, 0, result.labels, runs=3, fraction=0.8)
    assert found["stability"] < FOUND, found


def test_a_style_split_in_two_is_flagged_as_two_clusters_that_look_like_one():
    ds = make_dataset(n_per_style=60, styles=2)
    rng = np.random.default_rng(0)
    labels = np.asarray(ds.styles).copy()
    halves = np.flatnonzero(labels == 0)
    labels[rng.choice(halves, size=len(halves) // 2, replace=False)] = 2  # style 0 cut at random
    found = stability(ds, ClusterConfig(k=3), 0, labels, runs=2, fraction=0.8)
    assert found["merged_pairs"] >= 1 and "merged_pair_0_2" in found, found
    said = verdict_of({**found, "auto_fell_back": 1.0}, 3)
    assert "clusters 0 and 2 look like one style" in said.reasons
    assert "bag_auto fell back to policy_mix (continuous states)" in said.reasons
    assert verdict_of({}).verdict == "not measured"


def test_a_candidates_collapse_is_no_evidence_however_stable_the_kept_fit():
    base = {"n_clusters_used": 3.0, "auto_clusters_used_greedy_mix": 1.0}
    for s in (FOUND - 0.01, FOUND, 1.0):
        said = verdict_of({**base, "stability": s}, 3)
        assert said.verdict == "no evidence of 3 styles", said
        assert said.reasons[1] == "in greedy_mix's fit only 1 of 3 clusters hold trajectories"
    filled = {"n_clusters_used": 3.0, "auto_clusters_used_greedy_mix": 3.0, "stability": 0.6}
    assert verdict_of(filled, 3).verdict == "weak evidence"
    tagged = {
        f"clustering/{key}": v for key, v in base.items()
    }  # as MLflow and the report hold them
    assert verdict_of({**tagged, "clustering/stability": 0.6}, 3).verdict.startswith("no evidence")
