"""What a zoo game is, and how its episodes become a pcpg step table.

A game is a real environment (a Gymnasium env, a PettingZoo or OpenSpiel game) played by a few
scripted styles that all play competently but differently, with per-episode noise. An episode is
the states it saw (one more than its actions: the state after the last action closes it), the
discrete actions taken and their rewards. :func:`step_table` turns episodes into the table that
`domain: trajectories` reads (docs/bring-your-own-data.md): ``trajectory, t, s0..s{d-1}, action,
reward, style`` with ``action = -1`` on each trajectory's closing row.
"""

from __future__ import annotations

import importlib
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

ZOO = Path(__file__).resolve().parent


@dataclass
class Episode:
    """One episode: ``states`` (T + 1, d) floats, ``actions`` (T,) ints in 0..n-1, ``rewards`` (T,);
    ``valid`` (T, n) bools where the game logs which actions were legal (the table's ``valid``)."""

    states: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    valid: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.states = np.asarray(self.states, np.float32)
        self.actions = np.asarray(self.actions, np.int64)
        self.rewards = np.asarray(self.rewards, np.float64)
        t = len(self.actions)
        if self.states.ndim != 2 or len(self.states) != t + 1 or len(self.rewards) != t or t < 1:
            raise ValueError(
                f"an episode needs states (T + 1, d), actions (T,), rewards (T,) with T >= 1; got "
                f"{self.states.shape}, {self.actions.shape}, {self.rewards.shape}"
            )
        if self.valid is not None:
            self.valid = np.asarray(self.valid, bool)
            if self.valid.shape[0] != t or not self.valid[np.arange(t), self.actions].all():
                raise ValueError("an episode's valid masks need one row per action, allowing it")


def record(
    env,
    obs,
    act: Callable[[object, list], int],
    env_action: Callable[[int], object] = lambda a: a,
    observe: Callable[[object], np.ndarray] = lambda o: o,
) -> Episode:
    """Play a Gymnasium ``env`` just reset to ``obs`` until it terminates or truncates:
    ``act(obs, states)`` picks each action id (``states``: the recorded states so far), sent as
    ``env_action(id)``; ``observe(obs)`` is the state recorded. Closes the env."""
    states, actions, rewards = [observe(obs)], [], []
    done = False
    while not done:
        a = act(obs, states)
        obs, r, terminated, truncated, _ = env.step(env_action(a))
        states.append(observe(obs))
        actions.append(a)
        rewards.append(r)
        done = terminated or truncated
    env.close()
    return Episode(np.array(states), np.array(actions), np.array(rewards))


@dataclass(frozen=True)
class Game:
    """A zoo game.

    ``play(style, seed)`` plays one episode of ``style`` (0..len(styles)-1) whose noise and task
    (start, layout, opponent) come from ``seed`` alone. ``counts`` is how many episodes each style
    plays (unequal on purpose in some games); ``ci_counts`` the smaller numbers CI builds.
    ``kinds`` says which of the zoo's required shapes the game covers. ``held_out`` games take no
    part in any design decision of the clusterers and are reported apart (docs/zoo.md); ``blind``
    ones were also written after every design choice, and read once with the default as it stood."""

    name: str
    package: str
    kinds: tuple[str, ...]
    styles: tuple[str, ...]
    counts: tuple[int, ...]
    ci_counts: tuple[int, ...]
    n_actions: int
    play: Callable[[int, int], Episode]
    gymnasium_env: str | None = None
    gymnasium_kwargs: dict = field(default_factory=dict)
    held_out: bool = False
    blind: bool = False  # held out and written after every design choice, read once


def load_game(name: str) -> Game:
    """The ``GAME`` of ``benchmarks/zoo/<name>/generator.py``."""
    return importlib.import_module(f"benchmarks.zoo.{name}.generator").GAME


def game_names() -> list[str]:
    """Every game folder of the zoo, in name order."""
    return sorted(p.parent.name for p in ZOO.glob("*/generator.py"))


def design_games(asked: list[str], error: Callable[[str], object]) -> list[str]:
    """``asked`` (default: every design game), after ``error`` was called for any held-out or
    unknown game: the held-out games take no part in design decisions."""
    design = [g for g in game_names() if not load_game(g).held_out]
    for g in asked:
        if g not in design:
            error(f"{g}: not a design game of the zoo (held-out games are not searched)")
    return list(asked) or design


def overrides(pairs: list[str]) -> dict:
    """``--set KEY=VALUE`` arguments as clustering keys, each value read as JSON (8, "auto")."""
    return {k: json.loads(v) for k, v in (kv.split("=", 1) for kv in pairs)}


def policy_mix_from(ds, states, offsets, cfg, seed: int, start) -> np.ndarray:
    """policy_mix's EM labels from the labels ``start`` (its first round 4x longer, as after the
    default latent start), under a torch RNG forked and seeded with ``seed``."""
    import torch

    from pcpg_dist.stages.clustering.policy_mix import LATENT_FIRST_ROUND, _fit_policy_mix

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        labels, *_ = _fit_policy_mix(
            ds, states, offsets, cfg, seed, {}, start=start,
            first_round_steps=LATENT_FIRST_ROUND * cfg.policy_steps,
        )  # fmt: skip
    return labels


def episodes(game: Game, ci: bool = False, seed: int = 0) -> list[tuple[int, Episode]]:
    """Every (style, episode) of the game, each episode seeded from (seed, style, index) alone."""
    counts = game.ci_counts if ci else game.counts
    out = []
    for style, n in enumerate(counts):
        for i in range(n):
            episode_seed = int(np.random.SeedSequence([seed, style, i]).generate_state(1)[0])
            out.append((style, game.play(style, episode_seed)))
    return out


def step_table(played: list[tuple[int, Episode]], labelled: bool = True) -> pd.DataFrame:
    """The episodes as one step table (style -1 throughout when not ``labelled``)."""
    frames = []
    for traj, (style, ep) in enumerate(played):
        t = len(ep.actions)
        frame = pd.DataFrame(ep.states, columns=[f"s{j}" for j in range(ep.states.shape[1])])
        frame.insert(0, "t", np.arange(t + 1))
        frame.insert(0, "trajectory", traj)
        frame["action"] = np.append(ep.actions, -1)
        frame["reward"] = np.append(ep.rewards, 0.0)
        if ep.valid is not None:  # the closing row (no action) allows every action
            closing = np.ones((1, ep.valid.shape[1]), bool)
            frame["valid"] = list(np.vstack([ep.valid, closing]))
        frame["style"] = style if labelled else -1
        frames.append(frame)
    return pd.concat(frames, ignore_index=True)
