"""The domain API's defaults: the trajectory split, the paper's skill score, the in-process fan-out.

A domain that defines no ``units`` splits each dataset with :func:`split_trajectories`, and one
whose ``score`` returns None is ranked by :func:`performance` (Eq. 3). A domain's ``generate``
hands batches of calls to a fan-out: the orchestration passes one that runs them as Ray tasks
(``pcpg_dist.orchestration.ray_pool.fan_out``); a domain used on its own (a test, a notebook,
:func:`pcpg_dist.domains.check.check_domain`) gets :func:`in_process`, a plain loop. Results are
the same either way: every call is deterministic in its arguments. They live with the domain
API, not with Step B, so that the API (and the contract that checks a domain's score) needs
nothing above it; Step B (``pcpg_dist.stages.ranking``) calls the very same functions.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from pcpg_dist.common.errors import DataError
from pcpg_dist.common.progress import progress_bar

if TYPE_CHECKING:
    from pcpg_dist.config.ranking import RankConfig
    from pcpg_dist.dataset import Dataset
    from pcpg_dist.domains.base import ScoreFn


def performance(dataset: Dataset, beta: float = 0.1) -> np.ndarray:
    """Eq. 3 of the paper: ``(1/|X|) * (1 if X ends in a goal state else beta)``.

    |X| is the number of states of the trajectory; "goal" is ``dataset.success``. Shorter
    successful trajectories score highest, failures are scaled down by ``beta``.
    """
    lengths = dataset.lengths.astype(np.float64)
    return np.where(dataset.success, 1.0, beta) / lengths


def split_trajectories(n: int, test_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A seeded random split of positions 0..n-1 into sorted (train, test) index arrays.

    ``round`` decides the test size; with ``test_fraction > 0`` at least one trajectory is held
    out (the evaluation needs one) and at least one stays in training.
    """
    if n < 1:
        raise DataError("cannot split an empty dataset")
    if not 0.0 <= test_fraction < 1.0:
        raise DataError(f"test_fraction must lie in [0, 1), got {test_fraction}")
    n_test = min(n - 1, int(round(test_fraction * n)))
    if test_fraction > 0:
        if n < 2:
            raise DataError(
                f"ranking.test_fraction: {n} trajectory cannot be split into training "
                "and test trajectories (need at least 2)"
            )
        n_test = max(1, n_test)
    perm = np.random.default_rng(seed).permutation(n)
    return np.sort(perm[n_test:]), np.sort(perm[:n_test])


def score_dataset(dataset: Dataset, cfg: RankConfig, score: ScoreFn | None = None) -> np.ndarray:
    """Scores from a domain's own ``score`` callable, or Performance (Eq. 3) by default."""
    values = performance(dataset, cfg.beta) if score is None else np.asarray(score(dataset), float)
    if values.shape != (dataset.n_trajectories,):
        raise DataError(
            f"domain {dataset.domain!r}: its score function returned shape {values.shape} for "
            f"{dataset.env}; it must return one number per trajectory, shape "
            f"({dataset.n_trajectories},)"
        )
    if not np.isfinite(values).all():
        bad = np.flatnonzero(~np.isfinite(values))
        raise DataError(
            f"{dataset.domain}-{dataset.env}: the skill score of trajectory "
            f"{dataset.trajectory_ids[bad[0]]} is {values[bad[0]]} ({len(bad)} of "
            f"{dataset.n_trajectories} trajectories not finite); Step B ranks by finite scores: "
            f"check the domain's score setting and the values it adds up (rewards near "
            f"float64's limit overflow when summed)"
        )
    return values


def in_process(
    fn: Callable[..., Any],
    calls: Sequence[tuple],
    description: str,
    show_progress: bool = True,
) -> list[Any]:
    """Run ``fn(*args)`` for every ``args`` in ``calls`` here, one after another, with the same
    progress bar the Ray fan-out shows; results in call order."""
    results: list[Any] = []
    if not calls:
        return results
    with progress_bar(description, total=len(calls), enabled=show_progress) as advance:
        for args in calls:
            results.append(fn(*args))
            advance(1, description=description)
    return results
