"""Everything the paper reports about the trained agents, for one environment at a time.

Generic over domains: accuracy tables need only the Dataset and the ensemble; rollouts, rewards
and drawings come from callables a domain passes in (:class:`DomainHooks`). Definitions (also in
docs/bc_and_evaluation.md):

- *Accuracy* of a model on a set of trajectories: teacher-forced greedy prediction over all their
  step rows (action >= 0), pooled (micro average). PCPG at p pools pi_{k,p} on H_{k,p}^test over
  k; No Clustering at p is scored on the *same* rows (the union of the H_{k,p}^test), so the two
  are compared on identical data. Random = mean of 1/|valid actions| over those rows.
- *Cross accuracy* (Table 4): M[k, k'] = accuracy of pi_{k,p} on H_{k',p}^test, mean over p, seeds.
- *Correlation* (Fig. 7): C[k, k'] = Pearson correlation, over the test trajectories, between
  pi_{k,p}'s per-trajectory accuracy and the indicator "trajectory is in cluster k'" (a
  point-biserial correlation: > 0 when the model imitates that cluster better than the rest),
  mean over p and seeds.
- *Reward distance* (Table 3): |mean return of pi_k's rollouts under R_{style(k)} - optimal|,
  where style(k) is the majority true style of cluster k (identity when styles are unknown).
"""

from __future__ import annotations

import json
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from pcpg_dist.common.errors import DataError
from pcpg_dist.config.stages import EvalConfig
from pcpg_dist.dataset import Dataset
from pcpg_dist.domains.base import DomainHooks, Policy, random_policy  # noqa: F401 - DomainHooks re-exported
from pcpg_dist.stages.bc import TrainedCells
from pcpg_dist.stages.ranking import (
    RankConfig,
    ScoreFn,
    corrupt_labels,
    corruption_rng,
    fmt,
    ranked_last,
    score_dataset,
    threshold,
    threshold_all,
)


@dataclass(frozen=True)
class EvalResult:
    tables: dict[str, pd.DataFrame]
    metrics: dict[str, float]
    figures: dict[str, Path] = field(default_factory=dict)


# ---------------------------------------------------------------------- accuracy
class Scorer:
    """Per-trajectory correct-prediction counts of every cell on the test trajectories.

    Predictions depend on the state and mask only, so each distinct test row is predicted once.
    """

    def __init__(self, dataset: Dataset, test_idx: np.ndarray, trained: TrainedCells):
        if dataset.state_dim != trained.state_dim:
            raise DataError(
                f"dataset {dataset.env} has state width {dataset.state_dim}, the "
                f"models expect {trained.state_dim}"
            )
        self.test_idx = np.asarray(test_idx, np.int64)
        test = dataset.subset(self.test_idx)
        rows = test.step_rows
        valid = test.valid_mask[rows]
        key = np.concatenate([test.states[rows].view(np.int32), valid], axis=1)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        traj = test.row_trajectory[rows]
        n = test.n_trajectories
        self.steps = np.bincount(traj, minlength=n).astype(np.float64)
        self.random = np.bincount(traj, weights=1.0 / valid.sum(axis=1), minlength=n)
        self.correct = np.zeros((len(trained.specs), n))
        for i in range(len(trained.specs)):
            pred = trained.predict(test.states[rows][first], valid[first], i)[inverse]
            self.correct[i] = np.bincount(traj, weights=pred == test.actions[rows], minlength=n)
        self.position = {int(t): j for j, t in enumerate(self.test_idx)}

    def local(self, idx: np.ndarray) -> np.ndarray:
        """Dataset positions -> positions among the test trajectories."""
        return np.array([self.position[int(i)] for i in idx], np.int64)

    def accuracy(self, cell: int, idx: np.ndarray) -> float:
        loc = self.local(idx)
        steps = self.steps[loc].sum()
        return float(self.correct[cell, loc].sum() / steps) if steps else float("nan")

    def pooled(self, cells_and_subsets: list[tuple[int, np.ndarray]]) -> float:
        hits = sum(self.correct[c, self.local(i)].sum() for c, i in cells_and_subsets)
        steps = sum(self.steps[self.local(i)].sum() for _, i in cells_and_subsets)
        return float(hits / steps) if steps else float("nan")

    def random_accuracy(self, idx: np.ndarray) -> float:
        loc = self.local(idx)
        return float(self.random[loc].sum() / self.steps[loc].sum())


def _cell_table(trained: TrainedCells) -> dict[tuple, int]:
    table = {}
    for i, s in enumerate(trained.specs):
        ident = (s.kind, s.k, float(s.p), s.seed, float(s.c))
        if ident in table:
            raise DataError(
                f"cells {trained.specs[table[ident]].key} and {s.key} are the same "
                f"(kind, k, p, seed, c): pass one environment's ensemble"
            )
        table[ident] = i
    return table


def _mean_std(values: list[float]) -> tuple[float, float]:
    a = np.asarray(values, float)
    return float(np.nanmean(a)), float(np.nanstd(a)) if len(a) > 1 else 0.0


def style_of_clusters(dataset: Dataset, labels: np.ndarray, k: int) -> list[int]:
    """Majority true style of every cluster (identity where the styles are unknown; -1 for a
    cluster with no trajectory, possible when k exceeds the number of styles)."""
    if (dataset.styles < 0).any():
        return list(range(k))
    out = []
    for c in range(k):
        member = dataset.styles[labels == c]
        out.append(int(np.bincount(member).argmax()) if len(member) else -1)
    return out


# ---------------------------------------------------------------------- the evaluation
def evaluate(
    dataset: Dataset,
    labels: np.ndarray,
    test_idx: np.ndarray,
    trained: TrainedCells,
    rank_cfg: RankConfig,
    cfg: EvalConfig,
    out_dir: str | Path | None = None,
    hooks: DomainHooks | None = None,
    score: ScoreFn | None = None,
    k: int | None = None,
    margins: np.ndarray | None = None,
) -> EvalResult:
    """Tables, metrics and figures of one environment's ensemble; written to ``out_dir``.
    ``margins``: the clustering's, for ``rank_cfg.style_margin`` (the test subsets are ranked as
    the training subsets were)."""
    hooks = hooks or DomainHooks()
    labels = np.asarray(labels, np.int64)
    if labels.shape != (dataset.n_trajectories,):
        raise DataError(f"labels must have shape ({dataset.n_trajectories},), got {labels.shape}")
    k = int(labels.max()) + 1 if k is None else k
    test_idx = np.sort(np.asarray(test_idx, np.int64))
    if not len(test_idx):
        raise DataError("evaluation needs test trajectories (ranking.test_fraction > 0)")
    train_idx = np.setdiff1d(np.arange(dataset.n_trajectories), test_idx)
    cells = _cell_table(trained)
    seeds = sorted({s.seed for s in trained.specs})
    ps = [float(p) for p in rank_cfg.ps]
    scores = score_dataset(dataset, rank_cfg, score)
    last = ranked_last(margins, rank_cfg, dataset)
    ids = dataset.trajectory_ids
    h_test = threshold(labels, test_idx, scores, ids, ps, k, last)
    scorer = Scorer(dataset, test_idx, trained)
    tables: dict[str, pd.DataFrame] = {}
    metrics: dict[str, float] = {}
    if last is not None:
        metrics["ranking/ranked_last"] = float(last.mean())

    def put(name: str, values: list[float]) -> None:
        mean, std = _mean_std(values)
        metrics[name], metrics[f"{name}/std"] = mean, std

    # ---- Fig. 4: accuracy vs p, PCPG against No Clustering, random and the majority class
    # per trajectory: steps with an action, and how many of them are the training majority action
    traj, acts = dataset.row_trajectory, dataset.actions
    is_step = acts >= 0
    in_train = np.isin(traj, train_idx) & is_step
    majority = int(np.bincount(acts[in_train], minlength=dataset.n_actions).argmax())
    n_steps = np.bincount(traj, weights=is_step, minlength=dataset.n_trajectories)
    n_majority = np.bincount(traj, weights=acts == majority, minlength=dataset.n_trajectories)

    def majority_accuracy(idx: np.ndarray) -> float:
        """Accuracy of always predicting the training split's most frequent action (masks ignored)."""
        steps = n_steps[idx].sum()
        return float(n_majority[idx].sum() / steps) if steps else float("nan")

    rows = []
    for p in ps:
        union = np.unique(np.concatenate([h_test[(c, p)] for c in range(k)]))
        pc, nc, nc_own = [], [], []
        nc_test = threshold_all(test_idx, scores, ids, [p])[p]
        for seed in seeds:
            # a cluster without an agent (no training trajectory) is scored with No Clustering's
            pcpg = [
                (
                    cells.get(("pcpg", c, p, seed, 0.0), cells.get(("nc", -1, p, seed, 0.0))),
                    h_test[(c, p)],
                )
                for c in range(k)
            ]
            pcpg = [(cell, idx) for cell, idx in pcpg if cell is not None]
            if pcpg:
                pc.append(scorer.pooled(pcpg))
            if ("nc", -1, p, seed, 0.0) in cells:
                nc.append(scorer.accuracy(cells[("nc", -1, p, seed, 0.0)], union))
                nc_own.append(scorer.accuracy(cells[("nc", -1, p, seed, 0.0)], nc_test))
        rnd = scorer.random_accuracy(union)
        for method, vals in (
            ("pcpg", pc),
            ("no_clustering", nc),
            ("no_clustering_own_subset", nc_own),
        ):
            if vals:
                rows.append(
                    {
                        "method": method,
                        "p": p,
                        "mean": _mean_std(vals)[0],
                        "std": _mean_std(vals)[1],
                        "seeds": len(vals),
                    }
                )
        rows.append({"method": "random", "p": p, "mean": rnd, "std": 0.0, "seeds": 0})
        maj = majority_accuracy(union)
        rows.append({"method": "majority", "p": p, "mean": maj, "std": 0.0, "seeds": 0})
        metrics[f"majority/accuracy/p{fmt(p)}"] = maj
        if pc:
            put(f"pcpg/accuracy/p{fmt(p)}", pc)
        if nc:
            put(f"baseline/accuracy/p{fmt(p)}", nc)
        metrics[f"random/accuracy/p{fmt(p)}"] = rnd
        for c in range(k):
            vals = [
                scorer.accuracy(cells[("pcpg", c, p, s, 0.0)], h_test[(c, p)])
                for s in seeds
                if ("pcpg", c, p, s, 0.0) in cells
            ]
            if vals:
                put(f"pcpg/accuracy/k{c}/p{fmt(p)}", vals)
    metrics["random/accuracy"] = scorer.random_accuracy(test_idx)
    metrics["majority/accuracy"] = majority_accuracy(test_idx)
    tables["accuracy"] = pd.DataFrame(rows)
    if not (
        dataset.styles < 0
    ).any():  # which true style each cluster stands for (Tables 3-5 by style)
        sizes = np.bincount(labels, minlength=k)
        majority = style_of_clusters(dataset, labels, k)
        tables["cluster_style"] = pd.DataFrame(
            {
                "k": np.arange(k),
                "style": majority,
                "trajectories": sizes[:k],
                "purity": [
                    float(np.mean(dataset.styles[labels == c] == majority[c]))
                    if sizes[c]
                    else np.nan
                    for c in range(k)
                ],
            }
        )
    if any(
        f"pcpg/accuracy/p{fmt(p)}" in metrics and f"baseline/accuracy/p{fmt(p)}" in metrics
        for p in ps
    ):
        wins = [
            metrics[f"pcpg/accuracy/p{fmt(p)}"] > metrics[f"baseline/accuracy/p{fmt(p)}"]
            for p in ps
            if f"baseline/accuracy/p{fmt(p)}" in metrics
        ]
        metrics["pcpg/wins_over_baseline"] = float(np.mean(wins))

    # ---- Table 4 and Fig. 7: cross accuracy and model-vs-subset correlation, over the clusters
    # that have an agent (a clusterer may leave some of k empty: greedy_mix does when k is above
    # the styles its likelihood supports)
    used = [c for c in range(k) if all(("pcpg", c, p, s, 0.0) in cells for p in ps for s in seeds)]
    metrics["cross/clusters"] = float(len(used))
    if used:
        n_used = len(used)
        cross = np.zeros((len(seeds), len(ps), n_used, n_used))
        corr = np.zeros_like(cross)
        test_labels = labels[test_idx]
        has_steps = scorer.steps > 0
        for a, s in enumerate(seeds):
            for b, p in enumerate(ps):
                for row, c in enumerate(used):
                    i = cells[("pcpg", c, p, s, 0.0)]
                    per_traj = scorer.correct[i, has_steps] / scorer.steps[has_steps]
                    for col, c2 in enumerate(used):
                        cross[a, b, row, col] = scorer.accuracy(i, h_test[(c2, p)])
                        member = (test_labels[has_steps] == c2).astype(float)
                        ok = per_traj.std() > 0 and member.std() > 0
                        corr[a, b, row, col] = np.corrcoef(per_traj, member)[0, 1] if ok else 0.0
        names = [f"k{c}" for c in used]
        for name, arr in (("cross_accuracy", cross), ("correlation", corr)):
            per_seed = arr.mean(axis=1)
            tables[name] = pd.DataFrame(per_seed.mean(axis=0), index=names, columns=names)
            tables[f"{name}_std"] = pd.DataFrame(per_seed.std(axis=0), index=names, columns=names)
        m = cross.mean(axis=(0, 1))
        off = ~np.eye(n_used, dtype=bool)
        put(
            "cross/diagonal_mean",
            list(np.diagonal(cross.mean(axis=1), axis1=1, axis2=2).mean(axis=1)),
        )
        metrics["cross/offdiagonal_mean"] = float(m[off].mean()) if n_used > 1 else float("nan")
        metrics["cross/diagonal_is_row_max"] = float(np.mean(m.argmax(axis=1) == np.arange(n_used)))
        metrics["correlation/diagonal_mean"] = float(np.diagonal(corr.mean(axis=(0, 1))).mean())

    # ---- Fig. 6 from the data: mean length of the training subsets each agent imitates. The only
    # Fig. 6 a domain without a simulator (Mario) can have; beside rollouts it shows what they copy.
    h_train = threshold(labels, train_idx, scores, ids, ps, k, last)
    nc_train = threshold_all(train_idx, scores, ids, ps)

    def length_row(method: str, c: int, p: float, idx: np.ndarray) -> dict:
        kept = dataset.lengths[idx] - 1  # steps (actions taken), the unit of the rollouts' length
        return {
            "method": method,
            "k": c,
            "p": p,
            "mean": float(kept.mean()),
            "std": float(kept.std()),
            "n": len(idx),
        }

    subset_rows = [
        length_row("pcpg", c, p, h_train[(c, p)])
        for c in range(k)
        for p in ps
        if len(h_train[(c, p)])
    ]
    subset_rows += [length_row("nc", -1, p, nc_train[p]) for p in ps]
    tables["subset_length"] = pd.DataFrame(subset_rows)
    for row in subset_rows:
        who = "nc" if row["method"] == "nc" else f"k{row['k']}"
        metrics[f"subset/length/{who}/p{fmt(row['p'])}"] = row["mean"]

    # ---- rollouts: Table 3, Fig. 5/6, Fig. 8
    rollout_sets: dict[tuple, Dataset] = {}
    if hooks.rollout is not None:
        _rollouts(
            dataset,
            labels,
            k,
            seeds,
            ps,
            cells,
            trained,
            cfg,
            hooks,
            tables,
            metrics,
            rollout_sets,
            put,
        )

    # ---- Fig. 9 / Table 5: corruption study
    if any(kind == "corrupt" for kind, *_ in cells):
        _corruption(
            dataset,
            labels,
            k,
            seeds,
            cells,
            scorer,
            train_idx,
            test_idx,
            scores,
            last,
            rank_cfg,
            cfg,
            hooks,
            tables,
            metrics,
            put,
        )

    figures: dict[str, Path] = {}
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        for name, df in tables.items():
            df.to_csv(
                out / f"{name}.csv",
                index=name
                in ("cross_accuracy", "cross_accuracy_std", "correlation", "correlation_std"),
            )
            df.reset_index().to_json(out / f"{name}.json", orient="records", indent=1)
        (out / "metrics.json").write_text(json.dumps(metrics, indent=1, sort_keys=True))
        if cfg.figures:
            from pcpg_dist.stages import figures as fig

            figures = fig.write_all(tables, out, rollout_sets, hooks.draw, cfg.greedy)
    return EvalResult(tables, metrics, figures)


def over_seeds(runs: pd.DataFrame, col: str) -> pd.DataFrame:
    """Mean and std of ``col`` per agent (method, k, p) over its seeds; the std with ddof 0, as
    every std pcpg reports (the metrics' ``/std``), so a CSV and metrics.json never disagree."""
    return (
        runs.groupby(["method", "k", "p"])[col]
        .agg(mean="mean", std=lambda x: x.std(ddof=0))
        .reset_index()
    )


def rollout_rng(base: int, key: str) -> np.random.Generator:
    """The rollouts' generator of the agent ``key`` (a cell key): every table of one agent's
    rollouts (the evaluation's, a domain's extras) plays the same episodes."""
    return np.random.default_rng([base, zlib.crc32(key.encode())])


def _rollouts(
    dataset, labels, k, seeds, ps, cells, trained, cfg, hooks, tables, metrics, rollout_sets, put
) -> None:
    mode = "greedy" if cfg.greedy else "sampled"
    styles = style_of_clusters(dataset, labels, k)
    rows = []
    for (kind, c, p, seed, _), i in sorted(cells.items(), key=lambda x: x[1]):
        if kind not in ("pcpg", "nc"):
            continue
        ds = hooks.rollout(
            trained.policy(i, cfg.greedy),
            cfg.rollouts_per_policy,
            rollout_rng(cfg.rollout_seed, trained.specs[i].key),
        )
        row = {
            "method": kind,
            "k": c,
            "p": p,
            "seed": seed,
            "actions": mode,
            "length": float((ds.lengths - 1).mean()),
            "success": float(ds.success.mean()),
        }
        if hooks.returns is None:  # no per-style rewards: the environment's own return is the score
            row["return"] = float(ds.returns.mean())
        if hooks.returns is not None and kind == "pcpg":
            row["return_own_style"] = float(hooks.returns(ds, styles[c]).mean())
        rows.append(row)
        if kind == "pcpg" and seed == seeds[0] and p == cfg.reward_p:
            rollout_sets[(c, styles[c])] = ds.subset([0])
    runs = pd.DataFrame(rows)
    tables["rollouts"] = runs
    for col in ("length", "success", "return"):
        if col in runs:
            tables[f"rollout_{col}"] = over_seeds(runs, col)
    for (method, c, p), grp in runs.groupby(["method", "k", "p"]):
        who = f"k{c}" if method == "pcpg" else "nc"
        put(f"rollout/length/{who}/p{fmt(p)}", list(grp["length"]))
        put(
            f"rollout/success/{who}/p{fmt(p)}", list(grp["success"])
        )  # share of rollouts that succeed
        if "return" in grp:
            put(f"rollout/return/{who}/p{fmt(p)}", list(grp["return"]))
    if hooks.returns is None or hooks.optimal_return is None:
        return
    rnd = hooks.rollout(
        random_policy, cfg.rollouts_per_policy, rollout_rng(cfg.rollout_seed, "random")
    )
    dist_rows = []
    by_style: dict[tuple[int, float], list[float]] = {}  # two clusters of one majority style pool
    for c in range(k):
        style = styles[c]
        if style < 0:  # an empty cluster: no agent, no style
            continue
        best = float(hooks.optimal_return(style))
        rnd_dist = abs(float(hooks.returns(rnd, style).mean()) - best)
        metrics[f"random/reward_distance/style{style}"] = rnd_dist
        for p in sorted({float(p) for p in runs.p}, reverse=True):
            own = runs[(runs.method == "pcpg") & (runs.k == c) & (runs.p == p)]
            if not len(own):
                continue
            dists = list(np.abs(own["return_own_style"].to_numpy() - best))
            by_style.setdefault((style, p), []).extend(dists)
            dist_rows.append(
                {
                    "k": c,
                    "style": style,
                    "p": p,
                    "optimal": best,
                    "actions": mode,
                    "pcpg_mean": float(np.mean(dists)),
                    "pcpg_std": float(np.std(dists)),
                    "random": rnd_dist,
                    "headline": p == cfg.reward_p,
                }
            )
    for (style, p), dists in by_style.items():
        put(f"reward_distance/style{style}/p{fmt(p)}", dists)
        if p == cfg.reward_p:
            put(f"reward_distance/style{style}", dists)
    tables["reward_distance"] = pd.DataFrame(dist_rows)


def _corruption(
    dataset,
    labels,
    k,
    seeds,
    cells,
    scorer,
    train_idx,
    test_idx,
    scores,
    last,
    rank_cfg,
    cfg,
    hooks,
    tables,
    metrics,
    put,
) -> None:
    ids = dataset.trajectory_ids
    levels = sorted({c for kind, _, _, _, c in cells if kind == "corrupt"})
    ps = sorted({p for kind, _, p, _, _ in cells if kind == "corrupt"})
    h_true = threshold(labels, test_idx, scores, ids, ps, k, last)
    acc_rows, reward_rows = [], []
    # one return per true style's reward (k clusters may be more or fewer than the styles)
    n_rewards = (
        int(dataset.styles.max()) + 1 if len(dataset.styles) and dataset.styles.max() >= 0 else k
    )
    all_returns = (
        [hooks.returns(dataset, r) for r in range(n_rewards)] if hooks.returns is not None else None
    )
    for level in levels:
        acc, acc_true = [], []
        for seed in seeds:
            bad = corrupt_labels(
                labels,
                level,
                k,
                corruption_rng(rank_cfg.corruption_seed, seed, level),
                rank_cfg.corruption_mode,
            )
            h_bad = threshold(bad, test_idx, scores, ids, ps, k, last)
            h_train = threshold(bad, train_idx, scores, ids, ps, k, last)
            pairs = [
                (cells[("corrupt", c, p, seed, level)], h_bad[(c, p)], h_true[(c, p)])
                for c in range(k)
                for p in ps
                if ("corrupt", c, p, seed, level) in cells
            ]
            acc.append(scorer.pooled([(i, h) for i, h, _ in pairs]))
            acc_true.append(scorer.pooled([(i, h) for i, _, h in pairs]))
            if all_returns is not None:
                for c in range(k):
                    for p in ps:
                        members = h_train[(c, p)]
                        reward_rows.append(
                            {
                                "c": level,
                                "seed": seed,
                                "k": c,
                                "p": p,
                                **{
                                    f"R{r + 1}": float(all_returns[r][members].mean())
                                    if len(members)
                                    else float("nan")
                                    for r in range(n_rewards)
                                },
                            }
                        )
        put(f"corruption/accuracy/c{fmt(level)}", acc)
        put(f"corruption/accuracy_true_subsets/c{fmt(level)}", acc_true)
        acc_rows.append(
            {
                "c": level,
                "mean": _mean_std(acc)[0],
                "std": _mean_std(acc)[1],
                "true_subsets_mean": _mean_std(acc_true)[0],
                "true_subsets_std": _mean_std(acc_true)[1],
            }
        )
    nc = [
        scorer.pooled(
            [
                (
                    cells[("nc", -1, p, s, 0.0)],
                    np.unique(np.concatenate([h_true[(c, p)] for c in range(k)])),
                )
            ]
        )
        for s in seeds
        for p in ps
        if ("nc", -1, p, s, 0.0) in cells
    ]
    if nc:
        put("corruption/baseline/accuracy", nc)
    tables["corruption_accuracy"] = pd.DataFrame(acc_rows).assign(
        baseline_mean=_mean_std(nc)[0] if nc else np.nan
    )
    if reward_rows:
        raw = pd.DataFrame(reward_rows)
        cols = [f"R{r + 1}" for r in range(n_rewards)]
        mean = raw.groupby(["c", "k"])[cols].mean()
        std = raw.groupby(["c", "k"])[cols].std(ddof=0).add_suffix("_std")
        tables["corruption_reward"] = mean.join(std).reset_index()


def summarize(results: dict[str, EvalResult], out_dir: str | Path | None = None) -> EvalResult:
    """Across environments: every metric's mean over environments, tables stacked with ``env``."""
    names = sorted({m for r in results.values() for m in r.metrics})
    metrics = {}
    for name in names:
        vals = [r.metrics[name] for r in results.values() if name in r.metrics]
        metrics[name] = float(np.nanmean(vals))
    for env, r in results.items():
        for name, value in r.metrics.items():
            metrics[f"{env}/{name}"] = value
    tables = {}
    for name in sorted({t for r in results.values() for t in r.tables}):
        parts = [
            r.tables[name].reset_index().assign(env=env)
            for env, r in results.items()
            if name in r.tables
        ]
        tables[name] = pd.concat(parts, ignore_index=True)
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        for name, df in tables.items():
            df.to_csv(out / f"{name}.csv", index=False)
            df.to_json(out / f"{name}.json", orient="records", indent=1)
        (out / "metrics.json").write_text(json.dumps(metrics, indent=1, sort_keys=True))
    return EvalResult(tables, metrics, {})
