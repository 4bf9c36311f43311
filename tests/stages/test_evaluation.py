"""Evaluation on the two-style toy grid: every table the paper reports, with real thresholds."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from bc_toy import make_dataset, optimal_return, returns, rollout

from pcpg_dist.config.stages import BCConfig, EvalConfig
from pcpg_dist.domains.base import DomainHooks
from pcpg_dist.domains.defaults import split_trajectories
from pcpg_dist.stages.bc import train_cells
from pcpg_dist.stages.evaluation import Scorer, evaluate, summarize

# With k = 2, "wrong" labels at c = 0.5 are a fully random labelling: the clearest check.
from pcpg_dist.stages.ranking import RankConfig, plan_cells

# With k = 2, "wrong" labels at c = 0.5 are a fully random labelling: the clearest check.
RANK = RankConfig(ps=(1.0, 0.5, 0.25), corruption_mode="wrong")
EVAL = EvalConfig(rollouts_per_policy=10, corruption_levels=(0.0, 0.5))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    ds = make_dataset(120, seed=1)
    tr, te = split_trajectories(ds.n_trajectories, RANK.test_fraction, RANK.split_seed)
    cells = plan_cells(
        ds,
        ds.styles,
        tr,
        RANK,
        seeds=[0, 1],
        corruption_levels=EVAL.corruption_levels,
        corruption_ps=EVAL.corruption_ps,
    )
    model = train_cells(cells, BCConfig(epochs=1500))
    hooks = DomainHooks(
        rollout=rollout,
        returns=returns,
        optimal_return=optimal_return,
        draw=lambda ax, d: ax.plot(d.states[:, 0], d.states[:, 1]),
    )
    out = tmp_path_factory.mktemp("eval")
    return ds, te, model, evaluate(ds, ds.styles, te, model, RANK, EVAL, out, hooks), out


def test_pcpg_beats_no_clustering_and_random(run):
    _, _, _, res, _ = run
    m = res.metrics
    for p in ("1", "0.5", "0.25"):
        assert m[f"pcpg/accuracy/p{p}"] > m[f"baseline/accuracy/p{p}"] + 0.05
        assert m[f"baseline/accuracy/p{p}"] > m[f"random/accuracy/p{p}"]
    assert m["pcpg/wins_over_baseline"] == 1.0
    assert 0.25 < m["random/accuracy"] < 0.5  # 2 to 4 valid moves per cell of a 5x5 grid
    acc = res.tables["accuracy"]
    assert set(acc.method) >= {"pcpg", "no_clustering", "random"}


def test_cross_accuracy_diagonal_dominates(run):
    _, _, _, res, _ = run
    cross = res.tables["cross_accuracy"].to_numpy()
    assert (np.diag(cross) > cross.max(axis=1, initial=0, where=~np.eye(2, dtype=bool))).all()
    assert res.metrics["cross/diagonal_mean"] > 0.8
    assert res.metrics["cross/diagonal_is_row_max"] == 1.0
    corr = res.tables["correlation"].to_numpy()
    assert (np.diag(corr) > 0.3).all() and (corr[~np.eye(2, dtype=bool)] < 0).all()


def test_accuracy_matches_brute_force(run):
    ds, te, model, _, _ = run
    scorer = Scorer(ds, te, model)
    i = model.index("k1-p1-s1")
    idx = te[ds.styles[te] == 1]
    test = ds.subset(idx)
    rows = test.step_rows
    hits = [
        model.predict(test.states[r : r + 1], test.valid_mask[r : r + 1], i)[0] == test.actions[r]
        for r in rows
    ]
    assert scorer.accuracy(i, idx) == pytest.approx(np.mean(hits))
    assert scorer.random_accuracy(idx) == pytest.approx(np.mean(1 / test.valid_mask[rows].sum(1)))


def test_paired_lead_matches_brute_force_with_trajectories_as_units(run):
    ds, te, model, res, _ = run
    scorer = Scorer(ds, te, model)
    nc = model.index("nc-p1-s0")
    parts = [(model.index(f"k{c}-p1-s0"), te[ds.styles[te] == c]) for c in (0, 1)]
    lead, se = scorer.paired_lead(parts, nc)
    # by hand: per test trajectory, its agent's hits less No Clustering's, and its steps
    diff, steps = [], []
    for cell, idx in parts:
        for t in idx:
            test = ds.subset(np.array([t]))
            rows = test.step_rows
            x, v, a = test.states[rows], test.valid_mask[rows], test.actions[rows]
            diff.append(
                np.sum(model.predict(x, v, cell) == a) - np.sum(model.predict(x, v, nc) == a)
            )
            steps.append(len(rows))
    diff, steps = np.array(diff, float), np.array(steps, float)
    assert lead == pytest.approx(diff.sum() / steps.sum())
    assert lead == pytest.approx(scorer.pooled(parts) - scorer.accuracy(nc, te))
    resid = diff - lead * steps
    n = len(diff)
    assert se == pytest.approx(np.sqrt((resid**2).sum() * n / (n - 1)) / steps.sum())
    assert 0 < se < lead  # the toy's styles are clear: PCPG leads by more than one error
    # an agent against itself leads by nothing, exactly
    assert scorer.paired_lead([(nc, te)], nc) == (0.0, 0.0)
    m = res.metrics
    assert m["pcpg/lead_over_nc/p1"] == pytest.approx(
        m["pcpg/accuracy/p1"] - m["baseline/accuracy/p1"]
    )
    assert 0 < m["pcpg/lead_over_nc_se/p1"] < m["pcpg/lead_over_nc/p1"]


def test_rollouts_reward_distance_and_lengths(run):
    _, _, _, res, _ = run
    m = res.metrics
    for style in (0, 1):
        assert m[f"reward_distance/style{style}"] <= 5.0
        assert m[f"random/reward_distance/style{style}"] > 50.0
        # the optimal route is 8 moves; a good clone is close
        assert 8 <= m[f"rollout/length/k{style}/p0.25"] <= 10
    table = res.tables["reward_distance"]
    assert set(table.actions) == {"greedy"} and table.headline.sum() == 2
    assert m["reward_distance/style0/p1"] == m["reward_distance/style0"]
    # the kept data's length and the rollouts' are both in steps (actions taken): the best kept
    # quarter walks the 8-move route, as the clones do (the kept length counted states: 9)
    for style in (0, 1):
        assert 8 <= m[f"subset/length/k{style}/p0.25"] < 8.5


def test_two_clusters_of_one_style_pool_their_reward_distance(tmp_path):
    """reward_distance/style<s> was the last cluster of style s's figure: the others were dropped."""
    ds = make_dataset(120, seed=1)
    tr, te = split_trajectories(ds.n_trajectories, RANK.test_fraction, RANK.split_seed)
    labels = np.where(
        ds.styles == 1, 2, ds.trajectory_ids % 2
    )  # style 0 split over clusters 0 and 1
    rank = RankConfig(ps=(1.0, 0.5))
    model = train_cells(
        plan_cells(ds, labels, tr, rank, seeds=[0], k=3), BCConfig(epochs=100)
    )  # soft: sampled rollouts stray
    hooks = DomainHooks(rollout=rollout, returns=returns, optimal_return=optimal_return)
    cfg = EvalConfig(corruption_levels=(), rollouts_per_policy=10, figures=False, greedy=False)
    res = evaluate(ds, labels, te, model, rank, cfg, tmp_path, hooks, k=3)
    styles = res.tables["cluster_style"]
    assert list(styles["style"]) == [0, 0, 1] and list(styles["purity"]) == [1.0, 1.0, 1.0]
    table = res.tables["reward_distance"]
    own = table[table.headline & (table["style"] == 0)]
    assert list(own.k) == [0, 1]  # each cluster's own row, both kept
    assert own.pcpg_mean.nunique() == 2, own  # else the pooled and the last figure agree
    assert res.metrics["reward_distance/style0"] == pytest.approx(own.pcpg_mean.mean())


def test_corruption_falls_to_no_clustering(run):
    _, _, _, res, _ = run
    m = res.metrics
    assert m["corruption/accuracy/c0"] > m["corruption/accuracy/c0.5"] + 0.05
    # with 2 styles, c = 0.5 mixes both halves evenly: the baseline's situation
    assert abs(m["corruption/accuracy/c0.5"] - m["corruption/baseline/accuracy"]) < 0.04
    rew = res.tables["corruption_reward"].set_index(["c", "k"])
    # clean subsets collect their own bonus; half-corrupted ones are mixed
    assert rew.loc[(0.0, 0), "R1"] > 140 and rew.loc[(0.0, 0), "R2"] < 110
    assert 110 < rew.loc[(0.5, 0), "R1"] < 140


def test_outputs_written(run):
    _, _, _, res, out = run
    for name, df in res.tables.items():
        assert (out / f"{name}.csv").is_file()
        back = pd.read_json(out / f"{name}.json", orient="records")
        assert len(back) == len(df)
    assert json.loads((out / "metrics.json").read_text()) == pytest.approx(res.metrics, nan_ok=True)
    for name in (
        "accuracy_vs_p",
        "cross_accuracy",
        "correlation",
        "rollout_length",
        "corruption",
        "rollouts",
    ):
        png = res.figures[name]
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000


def test_summarize_averages_environments(run, tmp_path):
    _, _, _, res, _ = run
    s = summarize({"A": res, "B": res}, tmp_path)
    assert s.metrics["pcpg/accuracy/p1"] == pytest.approx(res.metrics["pcpg/accuracy/p1"])
    assert s.metrics["B/cross/diagonal_mean"] == res.metrics["cross/diagonal_mean"]
    assert set(s.tables["accuracy"].env) == {"A", "B"}


def test_style_of_an_empty_cluster_is_none():
    """k above the number of styles can leave a cluster without trajectories: no style (-1),
    never a style index the domain does not have."""
    from bc_toy import make_dataset

    from pcpg_dist.stages.evaluation import style_of_clusters

    ds = make_dataset(40, seed=1)
    labels = np.asarray(ds.styles, np.int64)
    styles = style_of_clusters(ds, labels, int(labels.max()) + 3)
    assert styles[: labels.max() + 1] == list(range(labels.max() + 1)) and styles[-2:] == [-1, -1]


def test_table_4_covers_the_clusters_that_have_agents(tmp_path):
    """A clusterer may leave some of its k clusters empty (greedy_mix does when k is above the
    styles its likelihood supports): Table 4 is then over the clusters with an agent, not dropped."""
    ds = make_dataset(120, seed=1)
    tr, te = split_trajectories(ds.n_trajectories, RANK.test_fraction, RANK.split_seed)
    labels = np.where(ds.styles == 1, 2, 0)  # k = 3, cluster 1 empty
    rank = RankConfig(ps=(1.0, 0.5))
    model = train_cells(plan_cells(ds, labels, tr, rank, seeds=[0], k=3), BCConfig(epochs=1500))
    res = evaluate(ds, labels, te, model, rank, EvalConfig(corruption_levels=()), tmp_path, k=3)
    assert res.metrics["cross/clusters"] == 2
    assert list(res.tables["cross_accuracy"].index) == ["k0", "k2"]
    assert (
        res.metrics["cross/diagonal_mean"] > 0.8 and res.metrics["cross/diagonal_is_row_max"] == 1.0
    )


def test_rollout_tables_and_metrics_give_one_std():
    """The rollout CSVs (and the report, which reads them) and metrics.json (MLflow) quote one
    std for one figure: over seeds, ddof 0 (the CSVs had pandas' ddof 1, sqrt(4/3) larger)."""
    from pcpg_dist.stages.evaluation import over_seeds
    from pcpg_dist.stages.evaluation.results import mean_std

    runs = pd.DataFrame(
        {
            "method": ["nc"] * 4 + ["pcpg"] * 2,
            "k": [-1] * 4 + [0, 0],
            "p": 1.0,
            "length": [10.0, 12.0, 14.0, 20.0, 7.0, 9.0],
        }
    )
    table = over_seeds(runs, "length").set_index("method")
    for method, values in (("nc", [10.0, 12.0, 14.0, 20.0]), ("pcpg", [7.0, 9.0])):
        assert table.loc[method, "mean"] == pytest.approx(np.mean(values))
        assert table.loc[method, "std"] == pytest.approx(np.std(values))  # ddof 0
        assert (table.loc[method, "mean"], table.loc[method, "std"]) == pytest.approx(
            mean_std(values)
        )
