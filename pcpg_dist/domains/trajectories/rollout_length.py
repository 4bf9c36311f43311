"""How many steps a ``trajectories`` rollout may take, and whether the Gymnasium env allows them.

Why a module of its own: the logs decide the length. ``evaluation.max_steps`` defaults to 100 for
every domain, which silently cut rollouts of a survival game (CartPole's logs run to 500 steps) to
a fifth of what the players did. Where the user left ``evaluation.max_steps`` unset, rollouts here
run up to the longest logged trajectory (at least the default); a value the user set stands. The
env's own time limit (``env.spec.max_episode_steps``) can still end episodes sooner than the logs
did, which is warned about, naming ``gymnasium_kwargs: {max_episode_steps: N}`` to raise it.

Nothing here changes the config: the evaluation's settings, the config hash and every other
domain's cache keys stay as they are.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import gymnasium

    from pcpg_dist.config.evaluation import EvalConfig
    from pcpg_dist.dataset import Dataset

log = logging.getLogger(__name__)


def longest_logged(datasets: Mapping[str, Dataset]) -> int:
    """The most actions any logged trajectory took, over every unit (0 where there are none): the
    Gymnasium env is one and the same for all units, so one length serves them all."""
    return max(
        (int(ds.lengths.max()) - 1 for ds in datasets.values() if ds.n_trajectories), default=0
    )


def rollout_steps(evaluation: EvalConfig, longest: int) -> int:
    """``evaluation.max_steps`` where the user set it, else the longest logged trajectory's number
    of actions or the default, whichever is larger (nothing else caps it)."""
    if "max_steps" in evaluation.model_fields_set:
        return evaluation.max_steps
    return max(longest, evaluation.max_steps)


def note_rollout_steps(evaluation: EvalConfig, longest: int) -> None:
    """One info line where the rollouts run longer than ``evaluation.max_steps`` says."""
    steps = rollout_steps(evaluation, longest)
    if steps != evaluation.max_steps:
        log.info(
            "trajectories: rollouts run up to %d steps, the longest logged trajectory "
            "(evaluation.max_steps not set)",
            steps,
        )


def warn_short_time_limit(env: gymnasium.Env, env_id: str, longest: int) -> None:
    """One warning line where the env's own time limit ends episodes before the longest logged
    trajectory did: the rollouts could then never play as long as the players."""
    limit = env.spec.max_episode_steps if env.spec is not None else None
    if limit is not None and limit < longest:
        log.warning(
            "trajectories: %s ends episodes after %d steps (its time limit) but the longest "
            "logged trajectory has %d; rollouts stop at %d unless trajectories.gymnasium_kwargs "
            "raises it: gymnasium_kwargs: {max_episode_steps: %d}",
            env_id,
            limit,
            longest,
            limit,
            longest,
        )
