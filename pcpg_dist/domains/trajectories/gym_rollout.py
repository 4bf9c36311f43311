"""Rolling trained agents out in a Gymnasium environment, for logs that came from one.

The ``trajectories`` domain reads a user's own logs; when ``trajectories.gymnasium_env`` names the
Gymnasium environment they were recorded in, every trained agent is rolled out there. The logs'
states must be ``gymnasium.spaces.flatten(observation_space, obs)`` (a ``Discrete`` observation is
a one-hot vector) and their actions ``0..n-1`` of a ``Discrete(n, start=s)`` action space (action
``a`` is sent to the environment as ``s + a``). :func:`check_compatible` checks both widths.

Valid actions: ``info["action_mask"]`` where the environment gives one (toy-text Taxi does), else
every action. Randomness: one seed per episode is drawn from the caller's generator before any
episode starts, and seeds both ``env.reset`` and ``env.action_space``; the policy draws from the
same generator afterwards, so one generator state gives one Dataset.

Gymnasium is imported inside the functions: this module is imported when a config is loaded.
"""

from __future__ import annotations

import re
import reprlib
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Literal, get_args

import numpy as np

from pcpg_dist.common.errors import ConfigError

if TYPE_CHECKING:
    import gymnasium

    from pcpg_dist.dataset import Dataset
    from pcpg_dist.domains.base import Policy

ENV_KEY = "trajectories.gymnasium_env"
KWARGS_KEY = "trajectories.gymnasium_kwargs"

#: How an episode's ``success`` is decided.
#: ``"terminated"``: the environment ended it itself (``terminated and not truncated``), not a
#: time limit nor ``max_steps``; right where termination means the goal (Taxi, MountainCar,
#: CliffWalking), wrong where it can mean failure (a FrozenLake hole, a fallen CartPole).
#: ``"terminated_positive_reward"``: terminated as above with a final reward > 0 (FrozenLake's goal
#: pays 1 and its holes 0; LunarLander lands at +100 and crashes at -100).
#: ``"reached_time_limit"``: survived: the env's time limit truncated it, or ``max_steps`` ended it,
#: without it terminating (CartPole, where terminating means the pole fell).
SuccessRule = Literal["terminated", "terminated_positive_reward", "reached_time_limit"]


def env_name(env_id: str) -> str:
    """``env_id`` as a plain file-name part (``ALE/Pong-v5`` -> ``ALE_Pong-v5``), for Dataset.env."""
    name = re.sub(r"[^A-Za-z0-9_.+-]", "_", env_id).replace("..", "_")
    return name if name[:1].isalnum() else f"env{name}"


def _one_line(e: BaseException) -> str:
    """The error's type and the first line of its message, cut to 300 characters."""
    text = next((line.strip() for line in str(e).splitlines() if line.strip()), "")
    text = text if len(text) <= 300 else text[:300] + "..."
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


_SHORT = reprlib.Repr()
_SHORT.maxstring, _SHORT.maxother, _SHORT.maxdict = 80, 80, 10


def _call(env_id: str, kwargs: Mapping[str, Any]) -> str:
    """How the env is made, for messages (long kwargs cut)."""
    return f"gymnasium.make({env_id!r}, **{_SHORT.repr(dict(kwargs))})"


def _env_key(kwargs: Mapping[str, Any]) -> str:
    """The key to blame when the env fails: its kwargs where some are given, else the id."""
    return KWARGS_KEY if kwargs else ENV_KEY


def make_env(env_id: str, kwargs: Mapping[str, Any]) -> gymnasium.Env:
    """``gymnasium.make(env_id, **kwargs)`` with a Discrete action space; ConfigError otherwise."""
    import gymnasium
    from gymnasium import spaces

    try:
        env = gymnasium.make(env_id, **dict(kwargs))
    except (gymnasium.error.UnregisteredEnv, gymnasium.error.DeprecatedEnv) as e:
        # an unknown or retired id: Gymnasium's own message names the close match ("Did you
        # mean: `FrozenLake`?") or the successor ("Please use `Taxi-v4` instead")
        hint = (
            " (an env a package registers when imported: name the package first, "
            "e.g. ale_py:ALE/Pong-v5)"
            if "Namespace" in str(e) and ":" not in env_id
            else ""
        )
        raise ConfigError(f"key '{ENV_KEY}': {' '.join(str(e).split())}{hint}") from None
    except Exception as e:  # whatever the env's constructor rejects is user input
        # ids like "module:Env-v0" import a module first; a missing one is the env key's fault
        missing = isinstance(e, ImportError | gymnasium.error.DependencyNotInstalled)
        key = ENV_KEY if missing else _env_key(kwargs)
        raise ConfigError(f"key '{key}': {_call(env_id, kwargs)} failed: {_one_line(e)}") from None
    if not isinstance(env.action_space, spaces.Discrete):
        space = env.action_space
        env.close()
        raise ConfigError(
            f"key '{ENV_KEY}': {env_id} has action space {space}; only Discrete action "
            f"spaces can be rolled out (logged actions are integers 0..n-1)"
        )
    return env


def check_runs(env: gymnasium.Env, env_id: str, kwargs: Mapping[str, Any]) -> None:
    """One ``reset()`` and one ``step()`` with a valid action, at config load: kwargs that fail only
    when the env runs (``render_mode: human`` without pygame, ...) are named before any work starts."""
    try:
        _, info = env.reset(seed=0)
        mask = np.asarray(info.get("action_mask", ()), bool).reshape(-1)
        first = int(np.argmax(mask)) if mask.any() else 0
        env.step(int(env.action_space.start) + first)
    except Exception as e:  # noqa: BLE001 - the user's env code: any error it raises is theirs to fix
        raise ConfigError(
            f"key '{_env_key(kwargs)}': {_call(env_id, kwargs)} fails on its first reset() "
            f"and step(): {_one_line(e)}"
        ) from None


def check_compatible(env: gymnasium.Env, state_dim: int, n_actions: int) -> None:
    """The environment's flattened observation width and number of actions equal the logs'."""
    from gymnasium import spaces

    env_id = env.spec.id if env.spec is not None else type(env.unwrapped).__name__
    if not isinstance(env.action_space, spaces.Discrete):
        raise ConfigError(
            f"key '{ENV_KEY}': {env_id} has action space {env.action_space}; only "
            f"Discrete action spaces can be rolled out"
        )
    try:
        width = spaces.flatdim(env.observation_space)
    except (ValueError, NotImplementedError) as e:
        raise ConfigError(
            f"key '{ENV_KEY}': {env_id}'s observation space {env.observation_space} "
            f"has no fixed flat width ({_one_line(e)})"
        ) from None
    n = int(env.action_space.n)
    if width != state_dim:
        raise ConfigError(
            f"key '{ENV_KEY}': {env_id} observations flatten to {width} features "
            f"({env.observation_space}) but the logs have {state_dim} state columns (s0..s{state_dim - 1}); "
            f"write each state as gymnasium.spaces.flatten(observation_space, obs) or name the env "
            f"(and {KWARGS_KEY}) the logs were recorded in"
        )
    if n != n_actions:
        rest = f"action {n_actions}" if n == n_actions + 1 else f"actions {n_actions}..{n - 1}"
        unused = (
            f"if the players never took {rest}, set trajectories.n_actions: {n}; "
            if n > n_actions
            else ""
        )
        raise ConfigError(
            f"key '{ENV_KEY}': {env_id} has {n} actions ({env.action_space}) but the logs have "
            f"{n_actions} (trajectories.n_actions, else the width of a 'valid' column, else the largest "
            f"action + 1); {unused}log actions as 0..{n - 1} or name the env (and {KWARGS_KEY}) the "
            f"logs were recorded in"
        )


def _mask(env_id: str, info: Mapping[str, Any], n_actions: int) -> np.ndarray:
    if "action_mask" not in info:
        return np.ones(n_actions, bool)
    mask = np.asarray(info["action_mask"]).astype(bool)
    if mask.shape != (n_actions,):
        raise ConfigError(
            f"key '{ENV_KEY}': {env_id} gives info['action_mask'] of shape "
            f"{mask.shape}, expected ({n_actions},) for its {n_actions} actions"
        )
    return mask


def _run_env(env_id: str, kwargs: Mapping[str, Any], episode: int, t: int, call, *args, **kw):
    """``call(*args, **kw)`` on the user's env; an error it raises becomes one ConfigError line
    naming the env (in a Ray task, rather than a traceback of the worker)."""
    try:
        return call(*args, **kw)
    except Exception as e:  # noqa: BLE001 - the user's env code: any error it raises is theirs to fix
        raise ConfigError(
            f"key '{_env_key(kwargs)}': {_call(env_id, kwargs)} failed in a rollout (episode "
            f"{episode}, step {t}, {call.__name__}()): {_one_line(e)}"
        ) from None


def rollout(
    env_id: str,
    kwargs: Mapping[str, Any],
    policy: Policy,
    n_episodes: int,
    rng: np.random.Generator,
    max_steps: int,
    action_names: tuple[str, ...] = (),
    feature_names: tuple[str, ...] = (),
    success_rule: SuccessRule = "terminated",
) -> Dataset:
    """``n_episodes`` episodes of ``policy`` in ``gymnasium.make(env_id, **kwargs)``, stepped together.

    Each episode has its own environment; the policy is called once per step on the live ones.
    An episode ends when the environment terminates or truncates it, or after ``max_steps``
    actions. Rewards are the environment's, one per action; ``success`` follows ``success_rule``
    (see :data:`SuccessRule`). A policy that returns an action outside the valid mask raises
    ValueError naming the episode and step.
    """
    from pcpg_dist.dataset import Dataset

    _check_rollout_arguments(n_episodes, max_steps, success_rule)
    seeds = [int(s) for s in rng.integers(2**31, size=n_episodes)]
    envs: list[gymnasium.Env] = []
    try:
        envs.extend(make_env(env_id, kwargs) for _ in range(n_episodes))
        run = _Episodes(env_id, kwargs, envs, success_rule)
        run.reset(seeds)
        for t in range(max_steps):
            live = np.nonzero(run.alive)[0]
            if not len(live):
                break
            masks = run.live_masks(live, t)
            acts = run.policy_actions(policy, live, masks, rng, t, action_names)
            run.step(live, acts, t)
        run.end_at_max_steps()
    finally:
        for env in envs:
            env.close()
    return Dataset.from_trajectories(
        "trajectories",
        env_name(env_id),
        run.n,
        run.trajectories(),
        styles=[-1] * n_episodes,
        success=run.success,
        feature_names=tuple(feature_names),
        action_names=tuple(action_names),
    )


def _check_rollout_arguments(n_episodes: int, max_steps: int, success_rule: str) -> None:
    if n_episodes < 1:
        raise ValueError(f"n_episodes must be >= 1, got {n_episodes}")
    if max_steps < 1:
        raise ValueError(f"max_steps must be >= 1, got {max_steps}")
    if success_rule not in get_args(SuccessRule):
        rules = ", ".join(repr(r) for r in get_args(SuccessRule))
        raise ValueError(f"success_rule must be one of {rules}, got {success_rule!r}")


class _Episodes:
    """Episodes stepped together, one environment each: what each has seen and done so far."""

    def __init__(
        self,
        env_id: str,
        kwargs: Mapping[str, Any],
        envs: list[gymnasium.Env],
        success_rule: SuccessRule,
    ) -> None:
        self.env_id, self.kwargs, self.envs, self.success_rule = env_id, kwargs, envs, success_rule
        self.obs_space, act_space = envs[0].observation_space, envs[0].action_space
        self.n, self.start = int(act_space.n), int(act_space.start)
        self.states: list[list[np.ndarray]] = [[] for _ in envs]
        self.valid: list[list[np.ndarray]] = [[] for _ in envs]
        self.actions: list[list[int]] = [[] for _ in envs]
        self.rewards: list[list[float]] = [[] for _ in envs]
        self.success = np.zeros(len(envs), bool)
        self.alive = np.ones(len(envs), bool)

    def _observe(self, i: int, obs: Any, info: Mapping[str, Any]) -> None:
        from gymnasium import spaces

        self.states[i].append(np.asarray(spaces.flatten(self.obs_space, obs), np.float32))
        self.valid[i].append(_mask(self.env_id, info, self.n))

    def reset(self, seeds: list[int]) -> None:
        for i, env in enumerate(self.envs):
            env.action_space.seed(seeds[i])
            obs, info = _run_env(self.env_id, self.kwargs, i, 0, env.reset, seed=seeds[i])
            self._observe(i, obs, info)

    def live_masks(self, live: np.ndarray, t: int) -> np.ndarray:
        """The live episodes' current masks; each must allow some action."""
        masks = np.stack([self.valid[i][-1] for i in live])
        if not masks.any(axis=1).all():
            i = int(live[np.argmin(masks.any(axis=1))])
            raise ConfigError(
                f"key '{ENV_KEY}': {self.env_id}'s action mask allows no action in episode "
                f"{i} at step {t}, yet the episode has not ended"
            )
        return masks

    def policy_actions(
        self,
        policy: Policy,
        live: np.ndarray,
        masks: np.ndarray,
        rng: np.random.Generator,
        t: int,
        action_names: tuple[str, ...],
    ) -> np.ndarray:
        """The policy's actions for the live episodes: integers, one each, valid where taken."""
        env_id, n = self.env_id, self.n
        acts = np.asarray(policy(np.stack([self.states[i][-1] for i in live]), masks, rng))
        if acts.shape != (len(live),) or not np.issubdtype(acts.dtype, np.integer):
            raise ValueError(
                f"{env_id} rollout, step {t}: the policy returned {acts.dtype} actions of "
                f"shape {acts.shape} for {len(live)} states, expected integers of shape ({len(live)},)"
            )
        in_range = (acts >= 0) & (acts < n)
        ok = in_range & masks[np.arange(len(live)), np.where(in_range, acts, 0).astype(np.int64)]
        if not ok.all():
            j = int(np.argmin(ok))
            a = acts[j]
            what = (
                f"action {a} ({action_names[int(a)]})"
                if in_range[j] and action_names
                else f"action {a}"
            )
            raise ValueError(
                f"{env_id} rollout, episode {int(live[j])}, step {t}: the policy chose "
                f"{what}, which is not valid there (valid: "
                f"{np.nonzero(masks[j])[0].tolist()} of 0..{n - 1})"
            )
        return acts

    def step(self, live: np.ndarray, acts: np.ndarray, t: int) -> None:
        for j, i in enumerate(live):
            a = int(acts[j])
            obs, reward, terminated, truncated, info = _run_env(
                self.env_id, self.kwargs, i, t, self.envs[i].step, self.start + a
            )
            self._observe(i, obs, info)
            self.actions[i].append(a)
            self.rewards[i].append(float(reward))
            if terminated or truncated:
                self.alive[i] = False
                self.success[i] = self._succeeded(bool(terminated), bool(truncated), float(reward))

    def _succeeded(self, terminated: bool, truncated: bool, reward: float) -> bool:
        """Whether an episode the env ended this way succeeded, by :data:`SuccessRule`."""
        if self.success_rule == "reached_time_limit":
            return truncated and not terminated
        return (terminated and not truncated) and (self.success_rule == "terminated" or reward > 0)

    def end_at_max_steps(self) -> None:
        """Episodes still live after ``max_steps`` actions end there: survivors, a success only
        under ``reached_time_limit``."""
        if self.success_rule == "reached_time_limit":
            self.success[self.alive] = True
        self.alive[:] = False

    def trajectories(self) -> list[dict[str, np.ndarray]]:
        return [
            {
                "states": np.stack(self.states[i]),
                "actions": np.asarray(self.actions[i], np.int64),
                "valid": np.stack(self.valid[i]),
                "rewards": np.asarray(self.rewards[i], np.float64),
            }
            for i in range(len(self.envs))
        ]
