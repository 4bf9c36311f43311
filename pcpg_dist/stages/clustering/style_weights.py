"""What each cluster weighs: a ``choice_mix`` clustering's preferences over the game's move
features (``clustering.move_features``), so that a user without labels can read what the styles
it found are.

Only a clustering by the moves' features has it; the evaluation writes it beside its tables
(``style_weights.csv``, and its figure), `pcpg cluster` beside its model, and the terminal says
what sets each cluster apart. Each weight is per standard deviation of its feature over the
log's legal moves: +1 multiplies the odds of a move by e for each standard deviation more of
that feature.
"""

from __future__ import annotations

import pandas as pd


def style_weights_of(model) -> pd.DataFrame | None:
    """A row per move feature (``feature``: named by the function's ``names``), a column per
    cluster (``k0`` ...); None for a clustering that is not ``choice_mix``."""
    if model is None or model.choice is None:
        return None
    from pcpg_dist.stages.clustering.move_pairs import feature_names, load_move_features

    w = model.choice[0]
    spec = model.move_features
    names = feature_names(load_move_features(spec), w.shape[1], spec)
    return pd.DataFrame({"feature": names, **{f"k{c}": w[c] for c in range(len(w))}})


def setting_apart(table: pd.DataFrame, top: int = 3) -> dict[str, list[tuple[str, float]]]:
    """Per cluster, the ``top`` features whose weight differs most from the clusters' mean
    weight on them (what sets that cluster apart), with that difference."""
    weights = table.drop(columns="feature")
    apart = weights.sub(weights.mean(axis=1), axis=0)
    out = {}
    for col in apart.columns:
        order = apart[col].abs().sort_values(ascending=False, kind="stable").index[:top]
        out[str(col)] = [(str(table.at[i, "feature"]), float(apart.at[i, col])) for i in order]
    return out


def apart_line(env: str, table: pd.DataFrame) -> str:
    """One line for the terminal: what sets each of ``env``'s clusters apart."""
    said = "; ".join(
        f"{c} " + ", ".join(f"{name} {v:+.1f}" for name, v in top)
        for c, top in setting_apart(table).items()
    )
    return (
        f"{env}: what sets each cluster apart (a move feature's weight beyond the clusters' "
        f"mean, per std. dev.; style_weights.csv): {said}"
    )
