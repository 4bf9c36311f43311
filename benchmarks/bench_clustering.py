"""Step A benchmark: every clusterer against the supervised ceiling, on E1-E5 and held-out layouts.

    uv run python benchmarks/bench_clustering.py --threads 1
    uv run python benchmarks/bench_clustering.py --methods bag_auto lstm_dec --heldout 0
    uv run python benchmarks/bench_clustering.py --groups heldout --heldout-seed 20261124 --methods bag_auto bag_kmeans
    uv run python benchmarks/bench_clustering.py --groups minidungeons --methods policy_mix lstm_dec

Data: the paper protocol's PBTG datasets (seed 0, 1000 trajectories per style) of E1-E5 and of
``--heldout`` fresh random style-distinct layouts (``gridworld.random_layouts`` family
``--heldout-seed``; the default family 9172024 is the issue's held-out bench, which no clusterer
was designed on; 20261124 is a second family, drawn for greedy_mix's final check, docs/clustering.md).
Datasets are cached as Parquet under ``--cache``.

Per dataset and method it prints accuracy (Hungarian), ARI, NMI, the gap to the ceiling (a 5-fold
cross-validated logistic regression given the true styles, pcpg_dist/stages/clustering/ceiling.py) and seconds; then
per method the mean and worst gap over E1-E5 and over the held-out layouts. On GridWorld it also
prints the Bayes rate (``bayes``): the accuracy of the generator's own classifier, which knows each
style's greedy policy (PBTG's Q-tables) and the noise range, and picks the style of highest
likelihood with each trajectory's noise level integrated out. No classifier beats it in
expectation; the summary gives each method's mean and worst gap to it as well. The off-the-shelf peer
is tslearn's TimeSeriesKMeans with DTW on the (x, y, b1, b2) sequences; DTW is O(n^2 T^2), so it
runs on a seeded subsample of ``--dtw-sample`` trajectories per dataset (said in the output).

The ``minidungeons`` group is the paper's MiniDungeons unit (780 trajectories, k = 6) at data
seeds ``--md-seeds``, prepared as ``pcpg run`` prepares it: the clusterer sees each level's states
standardised, the ceiling the raw ones (as in the pipeline's ``clustering/ceiling``).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
import warnings
from pathlib import Path

import numpy as np

from pcpg_dist.common.devices import set_threads
from pcpg_dist.dataset import read_parquet, write_parquet
from pcpg_dist.domains.gridworld import layout as gw
from pcpg_dist.domains.gridworld.pbtg import assemble_dataset, generate_pair
from pcpg_dist.domains.gridworld.settings import PBTGConfig
from pcpg_dist.stages.clustering import ClusterConfig, cluster, clustering_metrics
from pcpg_dist.stages.clustering.ceiling import gap_to_ceiling, supervised_ceiling

METHODS = (
    "bag_auto",
    "greedy_mix",
    "bag_kmeans",
    "bag_mop",
    "visits_kmeans",
    "summary_kmeans",
    "lstm_dec",
    "policy_mix",
    "dtw_kmeans",
)
ROOT = Path(__file__).resolve().parents[1]


def datasets(
    cache: Path, heldout: int, heldout_seed: int, groups: tuple[str, ...] = ("paper", "heldout")
):
    """(group, name, Dataset, Layout) for E1-E5 and the held-out layouts, generated once and cached."""
    layouts = []
    if "paper" in groups:
        layouts += [
            ("paper", gw.load_layout(ROOT / "pcpg_dist" / "data" / "gridworld" / f"E{i}.txt"))
            for i in range(1, 6)
        ]
    if "heldout" in groups:
        layouts += [("heldout", lt) for lt in gw.random_layouts(heldout, heldout_seed)]
    for group, lt in layouts:
        path = cache / group / f"{heldout_seed if group == 'heldout' else 'E'}_{lt.name}.parquet"
        if not path.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            write_parquet(
                assemble_dataset([generate_pair(lt, r, PBTGConfig(), 0) for r in range(4)]), path
            )
        yield group, lt.name, read_parquet(path), lt


def minidungeons_units(seeds: list[int]):
    """(group, name, raw Dataset, clustering input) of MiniDungeons' paper unit per data seed."""
    from dataclasses import replace

    from pcpg_dist.dataset import Dataset
    from pcpg_dist.domains.base import standardised
    from pcpg_dist.domains.minidungeons.data import (
        LEVELS_TEST,
        LEVELS_TRAIN,
        generate_trajectories,
        part_seed,
    )

    for seed in seeds:
        parts = [
            Dataset.concat(
                [generate_trajectories(lv, p, 10, part_seed(seed, lv, p)) for p in range(6)],
                renumber=True,
            )
            for lv in (*LEVELS_TRAIN, *LEVELS_TEST)
        ]
        yield (
            "minidungeons",
            f"seed{seed}",
            replace(Dataset.concat(parts), env="levels"),
            replace(Dataset.concat([standardised(p) for p in parts]), env="levels"),
        )


def bayes_rate(layout, ds, seed: int = 0, grid: int = 61) -> float:
    """Accuracy of the generator's classifier: each style's greedy policy from its Q-table (as
    :func:`pcpg_dist.domains.gridworld.pbtg.generate_pair` learns it for seed ``seed``), the step likelihood
    ``(1 - eps) [a = greedy] + eps / n_valid``, eps integrated over ``[noise_min, noise_max]``
    (its uniform prior), equal style priors."""
    from scipy.special import logsumexp

    from pcpg_dist.domains.gridworld.pbtg import pair_seed, q_learning

    cfg, t = PBTGConfig(), layout.tables  # the configuration :func:`datasets` generates with
    styles = np.unique(ds.styles)
    greedy = np.stack(
        [
            np.where(
                t.valid,
                q_learning(
                    t, int(r), cfg, int(pair_seed(seed, layout.name, int(r)).generate_state(3)[0])
                ),
                -np.inf,
            ).argmax(1)
            for r in styles
        ]
    )
    ids = {tuple(f): i for i, f in enumerate(t.features.tolist())}
    sid = np.array([ids[tuple(f)] for f in np.asarray(ds.states).tolist()])
    acts = np.asarray(ds.actions)
    step = acts >= 0
    traj = np.repeat(np.arange(ds.n_trajectories), np.diff(ds.offsets))[step]
    s, a = sid[step], acts[step]
    eps = np.linspace(max(cfg.noise_min, 1e-4), max(cfg.noise_max, 1e-4), grid)
    n_valid = t.valid.sum(1)[s][:, None]
    log_lik = np.empty((len(styles), ds.n_trajectories, grid))
    for i in range(len(styles)):
        p = np.where((greedy[i, s] == a)[:, None], 1 - eps + eps / n_valid, eps / n_valid)
        log_lik[i] = np.stack(
            [np.bincount(traj, np.log(p[:, j]), minlength=ds.n_trajectories) for j in range(grid)],
            axis=1,
        )
    return float((styles[logsumexp(log_lik, axis=2).argmax(0)] == ds.styles).mean())


def dtw_labels(ds, k: int, sample: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """tslearn TimeSeriesKMeans (DTW) on a seeded subsample: (sample indices, labels)."""
    from tslearn.clustering import TimeSeriesKMeans
    from tslearn.utils import to_time_series_dataset

    idx = np.sort(
        np.random.default_rng(seed).choice(
            ds.n_trajectories, min(sample, ds.n_trajectories), replace=False
        )
    )
    x = to_time_series_dataset([ds.trajectory_states(int(i)) for i in idx])
    km = TimeSeriesKMeans(n_clusters=k, metric="dtw", max_iter=10, n_init=1, random_state=seed)
    return idx, km.fit_predict(x)


def run_one(ds, method: str, seed: int, dtw_sample: int) -> dict[str, float]:
    start = time.perf_counter()
    k = len(np.unique(ds.styles))
    if method == "dtw_kmeans":
        idx, labels = dtw_labels(ds, k, dtw_sample, seed)
        true = ds.styles[idx]
    else:
        labels, true = cluster(ds, ClusterConfig(method=method, k=k), seed=seed).labels, ds.styles
    row = {"seconds": time.perf_counter() - start}
    row.update(clustering_metrics(true, labels))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--methods", nargs="*", default=list(METHODS), choices=METHODS)
    ap.add_argument("--heldout", type=int, default=20, help="number of held-out random layouts")
    ap.add_argument(
        "--heldout-seed", type=int, default=917_2024, help="random_layouts family of the bench"
    )
    ap.add_argument("--cache", type=Path, default=Path("data/bench_clustering"))
    ap.add_argument(
        "--groups",
        nargs="*",
        default=["paper", "heldout"],
        choices=["paper", "heldout", "minidungeons"],
    )
    ap.add_argument(
        "--md-seeds",
        nargs="*",
        type=int,
        default=[0, 1, 2, 3, 4],
        help="MiniDungeons data seeds (group minidungeons)",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--dtw-sample", type=int, default=300, help="trajectories per dataset for DTW")
    args = ap.parse_args()
    set_threads(args.threads)
    warnings.simplefilter("ignore")
    print(
        f"threads={args.threads} cpus={os.cpu_count()} load={os.getloadavg()[0]:.1f} "
        f"held-out family={args.heldout_seed} x{args.heldout}; dtw_kmeans on {args.dtw_sample} "
        f"trajectories per dataset (subsample)"
    )
    print(
        f"{'group':<13}{'env':<7}{'ceiling':>8}{'bayes':>7}{'method':>16}{'acc':>7}{'ARI':>7}{'NMI':>7}"
        f"{'gap':>8}{'s':>7}"
    )
    gaps: dict[tuple[str, str], list[float]] = {}
    bayes_gaps: dict[tuple[str, str], list[float]] = {}
    secs: dict[tuple[str, str], list[float]] = {}
    units = [
        (g, n, ds, ds, lt)
        for g, n, ds, lt in datasets(
            args.cache, args.heldout, args.heldout_seed, tuple(args.groups)
        )
    ]
    if "minidungeons" in args.groups:
        units = [*units, *((*u, None) for u in minidungeons_units(args.md_seeds))]
    for group, name, ds, cluster_input, layout in units:
        top = supervised_ceiling(ds, seed=args.seed)
        bayes = bayes_rate(layout, ds) if layout is not None else None
        for method in args.methods:
            r = run_one(cluster_input, method, args.seed, args.dtw_sample)
            gap = gap_to_ceiling(top, r["accuracy"])
            gaps.setdefault((group, method), []).append(gap)
            secs.setdefault((group, method), []).append(r["seconds"])
            if bayes is not None:
                bayes_gaps.setdefault((group, method), []).append(bayes - r["accuracy"])
            print(
                f"{group:<13}{name:<7}{top:>8.3f}{'–' if bayes is None else f'{bayes:.3f}':>7}{method:>16}{r['accuracy']:>7.3f}{r['ari']:>7.3f}"
                f"{r['nmi']:>7.3f}{gap:>+8.3f}{r['seconds']:>7.1f}",
                flush=True,
            )
    print("\nsummary: gap = ceiling - accuracy (target: mean and worst <= 0.010)")
    print(
        f"{'group':<13}{'method':>16}{'mean gap':>10}{'worst gap':>10}{'total s':>9}"
        f"{'mean to bayes':>15}{'worst to bayes':>16}"
    )
    for (group, method), g in gaps.items():
        b = bayes_gaps.get((group, method))
        to_bayes = f"{statistics.mean(b):>+15.4f}{max(b):>+16.4f}" if b else f"{'–':>15}{'–':>16}"
        print(
            f"{group:<13}{method:>16}{statistics.mean(g):>+10.4f}{max(g):>+10.4f}"
            f"{sum(secs[(group, method)]):>9.1f}{to_bayes}"
        )


if __name__ == "__main__":
    main()
