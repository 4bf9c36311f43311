"""Check one zoo game while writing it: do its styles play competently, and can a classifier
given the styles tell them apart (and how far is the label-free default)?

    uv run python -m benchmarks.zoo.check minigrid_empty [--full] [--cluster]

Prints each style's episodes, mean length and return, then the cross-validated accuracy of a
gradient-boosted classifier on the trajectories' profiles (pcpg_dist/stages/clustering/profile.py)
and of pcpg's supervised ceiling; with ``--cluster`` the default clusterer's accuracy too.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.zoo.common import episodes, load_game, step_table


def dataset_of(name: str, ci: bool, tmp: Path):
    """The game's episodes read back through pcpg's own step-table reader (one unit)."""
    (tmp / "steps").mkdir()
    table = step_table(episodes(load_game(name), ci=ci))
    table.to_parquet(tmp / "steps" / "steps.parquet", index=False)
    return read_unit(name, tmp / "steps")


def labelled_dataset(name: str, ci: bool):
    """The game's labelled unit (:func:`dataset_of`), its step table written to a temporary
    folder that is gone once the unit is read."""
    with tempfile.TemporaryDirectory() as tmp:
        return dataset_of(name, ci, Path(tmp))[2]


def read_unit(name: str, folder: Path):
    """(game, config, unit): the step table in ``folder`` (one written by :func:`dataset_of` or
    ``benchmarks.zoo.build``) read by pcpg's own step-table reader as ``domain: trajectories``."""
    from pcpg_dist.config import parse_config
    from pcpg_dist.domains import contract

    game = load_game(name)
    cfg = parse_config(
        {
            "name": f"check_{name}",
            "domain": "trajectories",
            "trajectories": {"path": str(folder), "n_actions": game.n_actions},
            "clustering": {"k": len(game.styles)},
        }
    )
    (ds,) = contract.generate(cfg, show_progress=False).values()
    return game, cfg, ds


def for_design_games(root: Path, games: list[str], error, run) -> None:
    """Print ``run(ds, k, truth)``'s lines for each design game's labelled unit under ``root``
    (``benchmarks.zoo.build --out``); ``error`` is called for a held-out or unknown game."""
    from benchmarks.zoo.common import design_games

    for name in design_games(games, error):
        game, _, ds = read_unit(name, root / name / "labelled")
        for line in run(ds, len(game.styles), np.asarray(ds.styles)):
            print(f"{name}: {line}", flush=True)


def supervised_profile_accuracy(ds, seed: int = 0) -> float:
    """5-fold cross-validated accuracy of gradient boosting on the trajectories' profiles."""
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.model_selection import StratifiedKFold, cross_val_score

    from pcpg_dist.stages.clustering.profile import trajectory_profiles

    x = trajectory_profiles(ds)
    folds = StratifiedKFold(5, shuffle=True, random_state=seed)
    model = HistGradientBoostingClassifier(max_iter=200, random_state=seed)
    return float(cross_val_score(model, x, ds.styles, cv=folds).mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("game")
    ap.add_argument("--full", action="store_true", help="the full counts (default: CI's)")
    ap.add_argument("--cluster", action="store_true", help="also the default clusterer")
    args = ap.parse_args()
    from pcpg_dist.common.devices import set_threads

    set_threads(1)  # as a pcpg task runs (oversubscribed torch is ~100x slower)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        game, cfg, ds = dataset_of(args.game, not args.full, Path(tmp))
        built = time.perf_counter() - t0
    print(
        f"{game.name}: {ds.n_trajectories} trajectories, {ds.n_rows} rows, "
        f"{ds.state_dim} features, {ds.n_actions} actions, built in {built:.1f} s"
    )
    for s, label in enumerate(game.styles):
        mine = ds.styles == s
        print(
            f"  style {s} {label:<28} {mine.sum():5d} episodes, length "
            f"{ds.lengths[mine].mean():7.1f}, return {ds.returns[mine].mean():8.2f}"
        )
    from pcpg_dist.stages.clustering.ceiling import supervised_ceiling

    print(
        f"  profile + gradient boosting (given the styles): {supervised_profile_accuracy(ds):.3f}"
    )
    print(f"  pcpg's supervised ceiling today: {supervised_ceiling(ds, seed=0):.3f}")
    if args.cluster:
        from pcpg_dist.stages.clustering import cluster, clustering_metrics

        t0 = time.perf_counter()
        result = cluster(ds, cfg.clustering, seed=0)
        acc = clustering_metrics(ds.styles, np.asarray(result.labels))["accuracy"]
        print(
            f"  default clusterer ({cfg.clustering.method}): {acc:.3f} "
            f"in {time.perf_counter() - t0:.1f} s"
        )


if __name__ == "__main__":
    main()
