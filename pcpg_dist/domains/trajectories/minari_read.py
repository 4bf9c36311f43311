"""Reading a LOCAL Minari dataset (``minari:DATASET_ID`` in a config) as pcpg's step table.

Each episode becomes one row per observation for :mod:`.table`. Minari stores ``T + 1``
observations and ``T`` actions per episode, so each episode gives ``T + 1`` rows, the last with
action -1 and reward 0. Observations are flattened exactly as ``gymnasium.spaces.flatten`` does
(Discrete -> one-hot, Box -> raveled, Dict/Tuple -> concatenated), but a whole episode at once.
Only a ``Discrete(n)`` action space fits pcpg. ``style`` comes from the episodes'
``infos["style"]`` (or the dataset metadata), a validity mask from ``infos["valid"]`` or
``infos["action_mask"]``.
"""

from __future__ import annotations

import difflib
import reprlib
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from pcpg_dist.common.errors import DataError, first_line
from pcpg_dist.dataset import check_action_memory
from pcpg_dist.domains.trajectories.minari_io import (
    ENV_VAR,
    STYLE_KEY,
    VALID_KEYS,
    check_id,
    check_local_dataset,
    env_name,
)


# --------------------------------------------------------------------------- observations
def flatten_observations(space: Any, values: Any) -> np.ndarray:
    """``(rows, flatdim)`` float32: ``gymnasium.spaces.flatten`` of every row of a decoded batch
    (an array, or a dict/tuple of them for Dict/Tuple spaces), computed without a per-row loop."""
    from gymnasium import spaces

    if isinstance(space, spaces.Box | spaces.MultiBinary):
        v = np.asarray(values)
        return v.reshape(len(v), -1).astype(np.float32)
    if isinstance(space, spaces.Discrete):
        idx = np.asarray(values).reshape(-1).astype(np.int64) - int(space.start)
        if idx.size and (idx.min() < 0 or idx.max() >= space.n):
            raise DataError(
                f"observation {int(idx[(idx < 0) | (idx >= space.n)][0]) + int(space.start)} "
                f"outside {space}"
            )
        out = np.zeros((len(idx), int(space.n)), np.float32)
        out[np.arange(len(idx)), idx] = 1.0
        return out
    if isinstance(space, spaces.MultiDiscrete):
        nvec = space.nvec.reshape(-1).astype(np.int64)
        v = np.asarray(values)
        idx = v.reshape(len(v), -1).astype(np.int64) - space.start.reshape(-1)
        if idx.size and ((idx < 0) | (idx >= nvec)).any():
            raise DataError(f"an observation lies outside {space}")
        out = np.zeros((len(idx), int(nvec.sum())), np.float32)
        out[np.arange(len(idx))[:, None], np.r_[0, np.cumsum(nvec)[:-1]] + idx] = 1.0
        return out
    if isinstance(space, spaces.Tuple) and space.spaces:
        return np.concatenate(
            [flatten_observations(s, values[i]) for i, s in enumerate(space.spaces)], axis=1
        )
    if isinstance(space, spaces.Dict) and space.spaces:
        return np.concatenate(
            [flatten_observations(s, values[k]) for k, s in space.spaces.items()], axis=1
        )
    if getattr(
        space, "is_np_flattenable", False
    ):  # Text, OneOf: rare, so the per-row flatten is fine
        return np.stack([spaces.flatten(space, x) for x in values]).astype(np.float32)
    raise DataError(f"observation space {space} cannot be flattened to a fixed-size state vector")


def observation_names(space: Any, prefix: str = "obs") -> list[str]:
    """One name per flattened feature, in :func:`flatten_observations` order (``obs.pos[1]``,
    ``obs=3`` for a one-hot Discrete entry)."""
    from gymnasium import spaces

    if isinstance(space, spaces.Box | spaces.MultiBinary):
        shape = tuple(space.shape)
        if len(shape) == 1:
            return [f"{prefix}[{i}]" for i in range(shape[0])]
        return [f"{prefix}[{','.join(map(str, ix))}]" for ix in np.ndindex(*shape)]
    if isinstance(space, spaces.Discrete):
        return [f"{prefix}={int(space.start) + i}" for i in range(int(space.n))]
    if isinstance(space, spaces.MultiDiscrete):
        starts = space.start.reshape(-1)
        return [
            f"{prefix}[{j}]={int(starts[j]) + v}"
            for j, n in enumerate(space.nvec.reshape(-1))
            for v in range(int(n))
        ]
    if isinstance(space, spaces.Tuple):
        return [
            n for i, s in enumerate(space.spaces) for n in observation_names(s, f"{prefix}.{i}")
        ]
    if isinstance(space, spaces.Dict):
        return [n for k, s in space.spaces.items() for n in observation_names(s, f"{prefix}.{k}")]
    return [f"{prefix}#{i}" for i in range(spaces.flatdim(space))]


# --------------------------------------------------------------------------- reading
def _load(dataset_id: str) -> tuple[Any, dict]:
    """The local Minari dataset ``dataset_id`` (never downloaded, its actions Discrete(n)) and its
    checked metadata (:func:`check_local_dataset`, before Minari reads it), or one-line DataError."""
    check_id(dataset_id)
    import minari
    from minari.storage import get_dataset_path

    path = Path(get_dataset_path(dataset_id))
    if not (path / "data").is_dir():
        root = Path(get_dataset_path())
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            local = list(minari.list_local_datasets())
        close = difflib.get_close_matches(dataset_id, local, n=3)
        hint = (
            f"; local datasets close to it: {', '.join(close)}"
            if close
            else (f"; the {len(local)} local ones include {', '.join(local[:3])}" if local else "")
        )
        raise DataError(
            f"minari:{dataset_id}: no local Minari dataset at {path} (Minari looks under "
            f"${ENV_VAR}, else ~/.minari/datasets; now {root}){hint}. Download it with "
            f"`minari download {dataset_id}` on a machine with network access, or set {ENV_VAR} to the folder that holds it"
        )
    meta = check_local_dataset(path, dataset_id)
    try:  # AssertionError: Minari asserts on what it reads
        dataset = minari.load_dataset(dataset_id, download=False)
    except (ValueError, KeyError, TypeError, OSError, AssertionError, pa.ArrowException) as e:
        raise DataError(
            f"minari:{dataset_id}: not a readable Minari dataset at {path} ({first_line(e)})"
        ) from None
    from gymnasium import spaces

    if not isinstance(dataset.action_space, spaces.Discrete):
        raise DataError(
            f"minari:{dataset_id}: action space {dataset.action_space}; pcpg needs a discrete "
            "action space (Discrete(n))"
        )
    return dataset, meta


def _episodes(dataset: Any, dataset_id: str) -> Iterator[Any]:
    """The episodes, with a read failure as one DataError (Minari raises several kinds, some when
    asked for the iterator: it reads every episode its metadata counts)."""
    errors = (ValueError, KeyError, TypeError, OSError, pa.ArrowException)

    def unreadable(e: BaseException) -> DataError:
        hint = (
            f"no such file {e}; does its metadata's total_episodes match the episodes stored?"
            if isinstance(e, FileNotFoundError)
            else first_line(e)
        )
        return DataError(f"minari:{dataset_id}: unreadable episode data ({hint})")

    try:
        it = iter(dataset.iterate_episodes())
    except errors as e:
        raise unreadable(e) from None
    while True:
        try:
            episode = next(it)
        except StopIteration:
            return
        except errors as e:
            raise unreadable(e) from None
        yield episode


def _per_row(values: Any, rows: int, what: str, where: str) -> np.ndarray:
    """An info series as ``rows`` entries: Minari's collectors store one per observation
    (``T + 1``); a series of one per action (``T``) gets its last entry repeated."""
    v = np.asarray(values)
    if len(v) == rows - 1 and rows > 1:
        v = np.concatenate([v, v[-1:]])
    if len(v) != rows:
        raise DataError(f"{where}: infos['{what}'] has {len(v)} entries for {rows} observations")
    return v


def _styles(values: Any, rows: int, where: str) -> np.ndarray:
    v = _per_row(values, rows, STYLE_KEY, where)
    if v.ndim != 1 or not (
        np.issubdtype(v.dtype, np.integer)
        or np.issubdtype(v.dtype, np.bool_)
        or (np.issubdtype(v.dtype, np.floating) and np.array_equal(v, np.round(v)))
    ):
        raise DataError(
            f"{where}: infos['style'] must hold one integer per step, got {v.dtype} {v.shape}"
        )
    return v.astype(np.int64)


def _valid_rows(infos: dict, rows: int, n_actions: int, where: str) -> np.ndarray | None:
    """The ``(rows, n_actions)`` validity mask from ``infos['valid']`` or ``infos['action_mask']``."""
    key = next((k for k in VALID_KEYS if k in infos), None)
    if key is None:
        return None
    mask = np.asarray(infos[key])
    if mask.ndim != 2 or mask.shape[1] != n_actions:
        raise DataError(
            f"{where}: infos['{key}'] has shape {mask.shape}, expected ({rows}, {n_actions})"
        )
    if len(mask) == rows - 1:  # one per action: nothing is known about the final state
        mask = np.concatenate([mask, np.ones((1, n_actions), mask.dtype)])
    return _per_row(mask, rows, key, where).astype(bool)


def _metadata_styles(metadata: dict, n_episodes: int, source: str) -> np.ndarray | None:
    """A dataset-level ``style``: one integer for every episode, or a list of one per episode."""
    raw = metadata.get(STYLE_KEY)
    if raw is None:
        return None
    v = np.atleast_1d(np.asarray(raw))
    if not np.issubdtype(v.dtype, np.integer) or v.ndim != 1 or len(v) not in (1, n_episodes):
        raise DataError(
            f"{source}: metadata 'style' must be an integer or a list of {n_episodes} integers"
        )
    return np.broadcast_to(v.astype(np.int64), (n_episodes,))


def read_minari(dataset_id: str) -> tuple[pa.Table, dict]:
    """A local Minari dataset as a pcpg step table, plus its metadata.

    Columns: ``trajectory`` (the episode id), ``t``, ``env`` (:func:`env_name` of the id),
    ``s0..s{d-1}`` (float32, the flattened observation), ``action`` (0..n-1, -1 on each episode's
    last row), ``reward`` (0 on the last row), ``success`` (the episode terminated, and was not
    truncated), and, when the data has them, ``style`` and ``valid``. A ``Discrete(n, start)``
    action ``a`` becomes ``a - start``. The metadata dict holds ``n_actions``, ``feature_names``,
    ``env_spec`` (its id or None), the spaces as text and, for data pcpg wrote, ``pcpg`` (domain,
    env, names). Episodes are decoded one at a time by Minari and joined once.
    """

    source = f"minari:{dataset_id}"
    dataset, checked = _load(dataset_id)
    action_space, obs_space = dataset.action_space, dataset.observation_space
    n_actions, start = int(action_space.n), int(action_space.start)
    raw_meta = dataset.storage.metadata
    eps = _Episodes()
    for ep in _episodes(dataset, dataset_id):
        eps.add(ep, obs_space, action_space, n_actions, start, f"{source}, episode {ep.id}")
    steps = int(np.asarray(eps.lengths).sum()) - len(eps.ids)
    if (len(eps.ids), steps) != (checked["total_episodes"], checked["total_steps"]):
        raise DataError(  # never a silent drop: Minari pairs episode ids with what it decoded
            f"{source}: metadata.json 'total_episodes' is {checked['total_episodes']:,} and "
            f"'total_steps' is {checked['total_steps']:,}; the episode files hold "
            f"{len(eps.ids):,} episodes of {steps:,} steps"
        )
    if not eps.ids:
        raise DataError(f"{source}: the dataset has no episodes")
    cols, d = eps.columns(env_name(dataset_id))
    meta_styles = _metadata_styles(raw_meta, len(eps.ids), source)
    eps.add_styles(cols, meta_styles)
    eps.add_valid(cols, n_actions, source, action_space)
    pcpg_meta = _pcpg_metadata(raw_meta, source)
    names = pcpg_meta.get("feature_names") or ()
    if len(names) != d:
        names = observation_names(obs_space)
    env_spec = dataset.env_spec
    meta = {
        "source": source,
        "dataset_id": dataset_id,
        "n_actions": n_actions,
        "action_start": start,
        "feature_names": list(names),
        "action_names": list(pcpg_meta.get("action_names") or ()),
        "env_spec": env_spec.id if env_spec is not None else None,
        "observation_space": str(obs_space),
        "action_space": str(action_space),
        "total_episodes": len(eps.ids),
        "total_steps": steps,
        "minari_version": str(raw_meta.get("minari_version", "")),
        "pcpg": pcpg_meta,
    }
    return pa.table(cols), meta


@dataclass
class _Episodes:
    """The episodes read so far, each checked and turned into its rows (one per observation)."""

    ids: list[int] = field(default_factory=list)
    states: list[np.ndarray] = field(default_factory=list)
    actions: list[np.ndarray] = field(default_factory=list)
    rewards: list[np.ndarray] = field(default_factory=list)
    success: list[bool] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    styles: list[np.ndarray | None] = field(default_factory=list)
    valids: list[np.ndarray | None] = field(default_factory=list)

    def add(
        self, ep: Any, obs_space: Any, action_space: Any, n_actions: int, start: int, where: str
    ) -> None:
        """One episode's rows, after its observations, actions and rewards agree in number and
        its actions lie in the action space."""
        steps = len(ep.rewards)
        try:
            obs = flatten_observations(obs_space, ep.observations)
        except DataError as e:
            raise DataError(f"{where}: {e}") from None
        if len(obs) != steps + 1:
            raise DataError(
                f"{where}: {len(obs)} observations for {steps} actions (Minari stores one "
                f"more observation than actions)"
            )
        act = np.asarray(ep.actions).reshape(-1).astype(np.int64) - start
        if len(act) != steps:
            raise DataError(f"{where}: {len(act)} actions for {steps} rewards")
        bad = (act < 0) | (act >= n_actions)
        if bad.any():
            raise DataError(
                f"{where}, step {int(np.argmax(bad))}: action {int(act[bad][0]) + start} "
                f"outside {action_space}"
            )
        self.ids.append(int(ep.id))
        self.states.append(obs)
        self.actions.append(np.r_[act, -1])
        self.rewards.append(np.r_[np.asarray(ep.rewards, np.float64).reshape(-1), 0.0])
        self.success.append(
            bool(steps) and bool(ep.terminations[-1]) and not bool(ep.truncations[-1])
        )
        self.lengths.append(steps + 1)
        infos = ep.infos or {}
        self.styles.append(
            _styles(infos[STYLE_KEY], steps + 1, where) if STYLE_KEY in infos else None
        )
        self.valids.append(_valid_rows(infos, steps + 1, n_actions, where))

    def columns(self, env: str) -> tuple[dict[str, pa.Array], int]:
        """The step table's columns every episode has, and the state width d."""
        lengths_a = np.asarray(self.lengths)
        rows = int(lengths_a.sum())
        offsets = np.r_[0, np.cumsum(lengths_a)[:-1]]
        cols: dict[str, pa.Array] = {
            "trajectory": pa.array(np.repeat(np.asarray(self.ids, np.int64), lengths_a)),
            "t": pa.array(np.arange(rows, dtype=np.int64) - np.repeat(offsets, lengths_a)),
            "env": pa.array([env] * rows, pa.string()),
        }
        all_states = np.concatenate(self.states)
        self.states = []  # the table holds its own copy
        d = all_states.shape[1]
        for j in range(d):
            cols[f"s{j}"] = pa.array(all_states[:, j], pa.float32())
        cols["action"] = pa.array(np.concatenate(self.actions))
        cols["reward"] = pa.array(np.concatenate(self.rewards))
        cols["success"] = pa.array(np.repeat(np.asarray(self.success, bool), lengths_a))
        return cols, d

    def add_styles(self, cols: dict[str, pa.Array], meta_styles: np.ndarray | None) -> None:
        """``style`` from the episodes' infos (-1 where an episode has none), else the metadata's."""
        if any(s is not None for s in self.styles):
            cols["style"] = pa.array(
                np.concatenate(
                    [
                        s if s is not None else np.full(n, -1, np.int64)
                        for s, n in zip(self.styles, self.lengths, strict=True)
                    ]
                )
            )
        elif meta_styles is not None:
            cols["style"] = pa.array(np.repeat(meta_styles, np.asarray(self.lengths)))

    def add_valid(
        self, cols: dict[str, pa.Array], n_actions: int, source: str, action_space: Any
    ) -> None:
        """``valid`` where some episode has masks (all actions valid where one has none)."""
        if not any(v is not None for v in self.valids):
            return
        check_action_memory(
            int(sum(self.lengths)), n_actions, source, f"its action space {action_space}"
        )
        mask = np.concatenate(
            [
                v if v is not None else np.ones((n, n_actions), bool)
                for v, n in zip(self.valids, self.lengths, strict=True)
            ]
        )
        cols["valid"] = pa.FixedSizeListArray.from_arrays(pa.array(mask.reshape(-1)), n_actions)


def _pcpg_metadata(raw_meta: dict, source: str) -> dict:
    """The ``pcpg`` metadata pcpg wrote (feature and action names); anything else is not trusted."""
    pcpg_meta = raw_meta.get("pcpg") if isinstance(raw_meta.get("pcpg"), dict) else {}
    for key in ("feature_names", "action_names"):
        value = pcpg_meta.get(key)
        if value is not None and not (
            isinstance(value, list) and all(isinstance(x, str) for x in value)
        ):
            raise DataError(
                f"{source}: metadata 'pcpg.{key}' is {reprlib.repr(value)}; expected a list of "
                f"names (strings), or no such key"
            )
    return pcpg_meta
