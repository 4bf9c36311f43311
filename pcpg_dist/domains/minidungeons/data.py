"""MiniDungeons trajectories: proxy generation, batched policy rollouts and outcome tables.

Everything here is a pure function of its arguments and an explicit seed or generator, so the
runner can fan :func:`generate_trajectories` out per (level, proxy) on Ray and join the parts with
:meth:`Dataset.concat <pcpg_dist.dataset.Dataset.concat>`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pcpg_dist.common.errors import ConfigError
from pcpg_dist.dataset import Dataset
from pcpg_dist.domains.base import Policy
from pcpg_dist.domains.minidungeons.game import (
    COUNT_SCALE,
    DEFAULT_MAX_STEPS,
    FEATURES,
    N_ACTIONS,
    STEP_SCALE,
    Game,
)
from pcpg_dist.domains.minidungeons.level import LEVELS_TEST, LEVELS_TRAIN, Level, load_level
from pcpg_dist.domains.minidungeons.proxies import N_PROXIES, PROXY_NAMES, act

DOMAIN = "minidungeons"
DEFAULT_NOISE = (0.0, 0.2)


def _level(level: str | Level) -> Level:
    return load_level(level) if isinstance(level, str) else level


def _record(game: Game) -> tuple[np.ndarray, int]:
    return game.features(), game.valid_mask()


def play(
    level: Level,
    proxy: int,
    epsilon: float,
    rng: np.random.Generator,
    max_steps: int = DEFAULT_MAX_STEPS,
) -> tuple[dict[str, np.ndarray], Game]:
    """One episode of a proxy; returns the trajectory dict of Dataset.from_trajectories and the game."""
    game = Game(level, max_steps)
    states, valid, actions, rewards = [], [], [], []
    s, v = _record(game)
    states.append(s)
    valid.append(v)
    while not game.over:
        a = act(game, proxy, epsilon, rng)
        r, _ = game.step(a, rng)
        actions.append(a)
        rewards.append(r)
        s, v = _record(game)
        states.append(s)
        valid.append(v)
    return {
        "states": np.stack(states),
        "actions": np.array(actions, np.int64),
        "valid": np.array(valid, bool),
        "rewards": np.array(rewards, np.float64),
    }, game


def generate_trajectories(
    level_name: str,
    proxy: int,
    n_runs: int,
    seed: int,
    noise_range: tuple[float, float] = DEFAULT_NOISE,
    max_steps: int = DEFAULT_MAX_STEPS,
) -> Dataset:
    """``n_runs`` episodes of one proxy on one level; each run's epsilon ~ U[noise_range].

    ``styles`` = proxy id, ``success`` = reached the exit, ``epsilon`` = the noise used.
    Same arguments, same Dataset: all randomness comes from ``np.random.default_rng(seed)``.
    """
    if not 0 <= proxy < N_PROXIES:
        raise ConfigError(
            f"proxy must be 0..{N_PROXIES - 1} ({', '.join(PROXY_NAMES)}), got {proxy}"
        )
    lo, hi = noise_range
    if not 0.0 <= lo <= hi <= 1.0:
        raise ConfigError(f"noise_range must satisfy 0 <= lo <= hi <= 1, got {noise_range}")
    if n_runs < 0:
        raise ConfigError(f"n_runs must be >= 0, got {n_runs}")
    level = _level(level_name)
    rng = np.random.default_rng(seed)
    trajs, success, eps = [], [], []
    for _ in range(n_runs):
        e = float(rng.uniform(lo, hi))
        tr, game = play(level, proxy, e, rng, max_steps)
        trajs.append(tr)
        success.append(game.success)
        eps.append(e)
    return Dataset.from_trajectories(
        DOMAIN,
        level.name,
        N_ACTIONS,
        trajs,
        styles=[proxy] * n_runs,
        success=success,
        epsilon=eps,
        feature_names=FEATURES,
    )


def default_dataset(
    seed: int,
    n_runs: int = 10,
    levels: tuple[str, ...] = (*LEVELS_TRAIN, *LEVELS_TEST),
    noise_range: tuple[float, float] = DEFAULT_NOISE,
) -> Dataset:
    """The paper's 780 trajectories (6 proxies x 13 levels x 10 runs), in one process.

    Each (level, proxy) part has its own seed derived from ``seed``, exactly as a Ray fan-out would
    use via :func:`part_seed`, so both give the same data.
    """
    parts = [
        generate_trajectories(lv, p, n_runs, part_seed(seed, lv, p), noise_range)
        for lv in levels
        for p in range(N_PROXIES)
    ]
    return Dataset.concat(parts)


def part_seed(seed: int, level_name: str, proxy: int) -> int:
    """A stable per-(level, proxy) seed (independent of Python's hash randomisation)."""
    key = [int(seed), proxy, *level_name.encode()]
    return int(np.random.SeedSequence(key).generate_state(1, np.uint64)[0] >> np.uint64(1))


def rollout(
    level: str | Level,
    policy: Policy,
    n_episodes: int,
    rng: np.random.Generator,
    max_steps: int = DEFAULT_MAX_STEPS,
) -> Dataset:
    """Roll a batched ``policy`` out ``n_episodes`` times; the live episodes share one call per turn.

    Fight damage draws from ``rng`` too. ``styles`` are -1; ``success`` = reached the exit.
    """
    level = _level(level)
    games = [Game(level, max_steps) for _ in range(n_episodes)]
    recs = [{"states": [], "valid": [], "actions": [], "rewards": []} for _ in games]
    for g, rec in zip(games, recs, strict=True):
        s, v = _record(g)
        rec["states"].append(s)
        rec["valid"].append(v)
    while True:
        live = [i for i, g in enumerate(games) if not g.over]
        if not live:
            break
        states = np.stack([recs[i]["states"][-1] for i in live])
        masks = np.stack([games[i].valid_mask() for i in live])
        acts = np.asarray(policy(states, masks, rng), np.int64).reshape(-1)
        if acts.shape != (len(live),):
            raise ValueError(f"policy returned {acts.shape} actions for {len(live)} states")
        if ((acts < 0) | (acts >= N_ACTIONS)).any() or not masks[np.arange(len(live)), acts].all():
            raise ValueError("policy returned an invalid (masked) action")
        for i, a in zip(live, acts, strict=True):
            r, _ = games[i].step(int(a), rng)
            s, v = _record(games[i])
            recs[i]["actions"].append(int(a))
            recs[i]["rewards"].append(r)
            recs[i]["states"].append(s)
            recs[i]["valid"].append(v)
    trajs = [
        {
            "states": np.stack(r["states"]),
            "actions": np.array(r["actions"], np.int64),
            "valid": np.array(r["valid"], bool),
            "rewards": np.array(r["rewards"], np.float64),
        }
        for r in recs
    ]
    return Dataset.from_trajectories(
        DOMAIN,
        level.name,
        N_ACTIONS,
        trajs,
        styles=[-1] * n_episodes,
        success=[g.success for g in games],
        feature_names=FEATURES,
    )


def outcome_stats(dataset: Dataset) -> pd.DataFrame:
    """Per-trajectory outcomes read back from the final state's features.

    Columns: trajectory, style, treasure, potions, kills, steps, died, success, hp (fraction of
    max). Counts are exact (features store count / 10); ``died`` = hit points 0 at the end.
    """
    if dataset.domain != DOMAIN:
        raise ConfigError(f"outcome_stats needs a {DOMAIN} dataset, got domain '{dataset.domain}'")
    last = dataset.states[dataset.offsets[1:] - 1].astype(np.float64)
    idx = {n: i for i, n in enumerate(FEATURES)}

    def count(name: str) -> np.ndarray:
        return np.rint(last[:, idx[name]] * COUNT_SCALE).astype(np.int64)

    return pd.DataFrame(
        {
            "trajectory": dataset.trajectory_ids,
            "style": dataset.styles,
            "treasure": count("treasure"),
            "potions": count("potions"),
            "kills": count("kills"),
            "steps": np.rint(last[:, idx["steps"]] * STEP_SCALE).astype(np.int64),
            "died": last[:, idx["hp"]] <= 0.0,
            "success": dataset.success.astype(bool),
            "hp": last[:, idx["hp"]],
        }
    )
