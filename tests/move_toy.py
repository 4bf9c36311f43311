"""A toy game whose move ids say nothing and whose moves' features say everything (for
``clustering.move_features``): 300 move ids, 6-14 legal each step, drawn at random. A state's
first number seeds what every move does; each style prefers moves by its own weights over the
four features."""

from __future__ import annotations

import numpy as np

from pcpg_dist.dataset import Dataset

N_ACTIONS = 300
PREFERENCES = np.array([[2.0, 0, 0, 0], [0, 2.0, 0, 0], [0, 0, 2.0, -1.0]])


def features(state: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(len(ids), 4): what each legal move does, a function of the state and the id."""
    ids = np.asarray(ids, np.float64)
    return np.stack([np.sin(state[0] * (ids + 1) + 1.7 * j) for j in range(4)], axis=1)


features.names = ["first", "second", "third", "fourth"]  # the style_weights table's rows


def wrong_names(state: np.ndarray, ids: np.ndarray) -> np.ndarray:
    return features(state, ids)


wrong_names.names = ["first", "second"]  # four features, two names


def playable_here(state: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Which ids are moves in ``state`` (about two in three): what a log without action masks
    does not say."""
    return (np.asarray(ids) * 7919 + int(state[0] * 1000)) % 3 != 0


def with_playable(state: np.ndarray, ids: np.ndarray):
    """The features and which offered ids are moves here (for a log that offers every id)."""
    return features(state, ids), playable_here(state, ids)


def none_playable(state: np.ndarray, ids: np.ndarray):
    return features(state, ids), np.zeros(len(ids), bool)


def playable_of_wrong_shape(state: np.ndarray, ids: np.ndarray):
    return features(state, ids), np.ones(len(ids) + 1, bool)


def wrong_width(state: np.ndarray, ids: np.ndarray) -> np.ndarray:
    return np.zeros((len(ids), 3 if state[0] > 1.5 else 4))


def with_nan(state: np.ndarray, ids: np.ndarray) -> np.ndarray:
    out = features(state, ids)
    out[0, 0] = np.nan
    return out


NOT_A_FUNCTION = 3


def players(n_per_style: int, seed: int, offered: int = 0) -> Dataset:
    """Three styles, ``n_per_style`` trajectories each of 8-20 moves; 10 % random legal moves.
    With ``offered``, the log's masks also offer that many ids a step that are no moves there
    (:func:`playable_here`), as a log without action masks does."""
    rng = np.random.default_rng(seed)
    trajs, styles = [], []
    for style, w in enumerate(PREFERENCES):
        for _ in range(n_per_style):
            t = int(rng.integers(8, 21))
            states = np.column_stack([rng.uniform(1, 2, t + 1), rng.normal(size=t + 1)])
            valid = np.zeros((t + 1, N_ACTIONS), bool)
            actions = np.zeros(t, np.int64)
            for i in range(t):
                moves = np.flatnonzero(playable_here(states[i], np.arange(N_ACTIONS)))
                legal = np.sort(rng.choice(moves, int(rng.integers(6, 15)), replace=False))
                valid[i, legal] = True
                if offered:
                    no_moves = np.flatnonzero(~playable_here(states[i], np.arange(N_ACTIONS)))
                    valid[i, rng.choice(no_moves, offered, replace=False)] = True
                score = features(states[i], legal) @ w + rng.gumbel(size=len(legal)) * 0.5
                pick = rng.integers(len(legal)) if rng.random() < 0.1 else np.argmax(score)
                actions[i] = legal[pick]
            valid[t] = True
            trajs.append({"states": states, "actions": actions, "valid": valid,
                          "rewards": np.zeros(t)})  # fmt: skip
            styles.append(style)
    return Dataset.from_trajectories("toy", "moves", N_ACTIONS, trajs, styles, [True] * len(trajs))
