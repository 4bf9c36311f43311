"""Experiment: clustering chess by what its moves do (twenty-seventh session).

    uv run python -m benchmarks.zoo.choice_exp ZOO_DIR [--seeds 0 1 2]

Blind chess sits at chance with every built-in clusterer: a move id says a from-square and a
direction, and the styles weigh captures, checks, pawn pushes and development. Here each legal
move of every step gets generic chess features (:mod:`benchmarks.zoo.chess.moves`, from the step
table's state and move id alone), and two things are measured on the labelled unit:

- given the styles (5-fold cross-validation): a logistic regression and gradient boosting on each
  trajectory's *revealed preferences* (the chosen move's features less the mean of the legal
  moves', averaged over its moves): what the features allow;
- without them: k-means on the standardised revealed preferences, and
  :func:`pcpg_dist.stages.clustering.choice_mix.fit_choice_mix` (a mixture of k conditional
  logits over the features), each seed, with its seconds.

The default's figures beside them are docs/zoo.md's (0.300 / 0.408 / 0.325, ceiling 0.745).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

SPEC = "benchmarks.zoo.chess.moves:move_features"


def chess_pairs(ds):
    """:class:`ChoicePairs` of the chess unit, as ``clustering.move_features`` builds them."""
    from pcpg_dist.stages.clustering.move_pairs import load_move_features, pairs_of

    return pairs_of(ds, load_move_features(SPEC), SPEC)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("zoo", type=Path)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    args = ap.parse_args()

    from sklearn.cluster import KMeans
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.linear_model import LogisticRegression
    from sklearn.model_selection import StratifiedKFold, cross_val_score
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    from benchmarks.zoo.check import read_unit
    from pcpg_dist.stages.clustering.choice_mix import fit_choice_mix, revealed_preferences
    from pcpg_dist.stages.clustering.metrics import clustering_metrics

    _, _, ds = read_unit("chess", args.zoo / "chess" / "labelled")
    truth = np.asarray(ds.styles)
    t0 = time.perf_counter()
    pairs = chess_pairs(ds)
    print(
        f"chess: {len(truth)} trajectories, {len(pairs.chosen)} moves, {len(pairs.phi)} legal "
        f"moves' features in {time.perf_counter() - t0:.1f} s"
    )
    prefs = revealed_preferences(pairs)
    folds = StratifiedKFold(5, shuffle=True, random_state=0)
    for name, model in (
        ("logistic", make_pipeline(StandardScaler(), LogisticRegression(max_iter=2000))),
        ("boosting", HistGradientBoostingClassifier(random_state=0)),
    ):
        acc = cross_val_score(model, prefs, truth, cv=folds).mean()
        print(f"  given the styles, {name} on revealed preferences: {acc:.3f}")
    scaled = StandardScaler().fit_transform(prefs)
    for seed in args.seeds:
        km = KMeans(len(set(truth)), n_init=10, random_state=seed).fit_predict(scaled)
        t0 = time.perf_counter()
        fit = fit_choice_mix(pairs, len(set(truth)), seed)
        labels, margins, ll = fit.labels, fit.margins, fit.loglik
        took = time.perf_counter() - t0
        print(
            f"  seed {seed}: k-means on revealed preferences "
            f"{clustering_metrics(truth, km)['accuracy']:.3f}; choice_mix "
            f"{clustering_metrics(truth, labels)['accuracy']:.3f} (log-lik {ll:.4f} a move, "
            f"median margin {np.median(margins):.1f} nats) in {took:.1f} s"
        )


if __name__ == "__main__":
    main()
