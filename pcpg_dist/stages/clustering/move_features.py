"""The ``choice_mix`` clusterer: a mixture of choice models over a game's own move features
(``clustering.move_features``; the features: :mod:`.move_pairs`, the model: :mod:`.choice_mix`).
``bag_auto`` uses it whenever the setting is given (docs/clustering.md, "What a move does")."""

from __future__ import annotations

import numpy as np

from pcpg_dist.common.devices import thread_budget
from pcpg_dist.common.errors import DataError
from pcpg_dist.stages.clustering.choice_mix import fit_choice_mix, posteriors
from pcpg_dist.stages.clustering.move_pairs import (
    KEY,
    feature_names,
    load_move_features,
    pairs_of,
)


def fit_choice(dataset, states, offsets, cfg, seed: int, metrics: dict[str, float]):
    """``choice_mix``'s fitting function (:data:`pcpg_dist.config.clusterers.CLUSTERERS`): the
    mixture over the move features of ``cfg.move_features``; its model assigns by likelihood."""
    from pcpg_dist.stages.clustering.model import ClusterModel, Fitted

    if cfg.move_features is None:
        raise DataError(
            f"clustering.method choice_mix needs {KEY}: 'package.module:function' that gives "
            "the legal moves' features of a state"
        )
    features = load_move_features(cfg.move_features)
    pairs = pairs_of(dataset, features, cfg.move_features)
    feature_names(features, pairs.phi.shape[1], cfg.move_features)  # checked before the fit
    fit = fit_choice_mix(pairs, cfg.k, seed, threads=thread_budget())
    metrics["choice_loglik_per_move"] = fit.loglik
    model = ClusterModel(
        "choice_mix",
        cfg.model_dump(mode="json"),
        states.shape[1],
        fit.mean,
        fit.std,
        np.eye(cfg.k),
        None,
        choice=(fit.w, fit.log_share),
        move_features=cfg.move_features,
    )
    latents = posteriors(fit.scores(pairs))
    return Fitted(fit.labels, latents, model, fit.margins, silhouette=False)
