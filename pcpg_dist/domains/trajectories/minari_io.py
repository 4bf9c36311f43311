"""Minari datasets <-> pcpg: read one as a step table, write pcpg datasets as Minari datasets.

Reading (``minari:DATASET_ID`` in a config): a LOCAL Minari dataset becomes the step table of
:mod:`.table`, one row per observation. Minari stores ``T + 1`` observations and ``T`` actions per
episode, so each episode gives ``T + 1`` rows, the last with action -1 and reward 0. Observations
are flattened exactly as ``gymnasium.spaces.flatten`` does (Discrete -> one-hot, Box -> raveled,
Dict/Tuple -> concatenated), but a whole episode at once. Only a ``Discrete(n)`` action space fits
pcpg. ``style`` comes from the episodes' ``infos["style"]`` (or the dataset metadata), a validity
mask from ``infos["valid"]`` or ``infos["action_mask"]``.

Writing (``pcpg export minari``): one Minari dataset per environment, observation space
``Box(-inf, inf, (d,), float32)``, action space ``Discrete(n_actions)``, per-step infos ``style``
and ``valid``, so that reading it back gives the same step table.
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import os
import re
import reprlib
import shutil
import socket
import tempfile
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from pcpg_dist.common.errors import DataError, first_line
from pcpg_dist.config.domains import MINARI_ID, minari_id_problem
from pcpg_dist.dataset import MANIFEST, Dataset, check_action_memory, load_datasets

ENV_VAR = "MINARI_DATASETS_PATH"
STYLE_KEY = "style"
VALID_KEYS = ("valid", "action_mask")
DATA_FORMAT = "arrow"  # installed with minari[arrow]; hdf5 would need h5py


def env_name(dataset_id: str) -> str:
    """The ``env`` value (a folder name) of a Minari dataset: its id with unsafe characters -> '_'."""
    from pcpg_dist.domains.trajectories.table_files import safe_env_name

    return safe_env_name(dataset_id)


def _check_id(dataset_id: str, need_version: bool = False) -> None:
    problem = minari_id_problem(dataset_id, need_version)
    if problem:
        raise DataError(problem)


@contextlib.contextmanager
def datasets_root(path: Path) -> Iterator[Path]:
    """Point Minari at ``path`` (``$MINARI_DATASETS_PATH``) for the block, then restore it.

    Minari reads the variable on every call, and has no other way to choose the folder.
    """
    old = os.environ.get(ENV_VAR)
    os.environ[ENV_VAR] = str(Path(path).resolve())
    try:
        yield Path(os.environ[ENV_VAR])
    finally:
        if old is None:
            os.environ.pop(ENV_VAR, None)
        else:
            os.environ[ENV_VAR] = old


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
def _load(dataset_id: str) -> Any:
    """The local Minari dataset ``dataset_id`` (never downloaded), or one-line DataError."""
    _check_id(dataset_id)
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
    try:
        return minari.load_dataset(dataset_id, download=False)
    except (ValueError, KeyError, TypeError, OSError, ImportError, pa.ArrowException) as e:
        raise DataError(
            f"minari:{dataset_id}: not a readable Minari dataset at {path} ({first_line(e)})"
        ) from None


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
    from gymnasium import spaces

    source = f"minari:{dataset_id}"
    dataset = _load(dataset_id)
    action_space, obs_space = dataset.action_space, dataset.observation_space
    if not isinstance(action_space, spaces.Discrete):
        raise DataError(
            f"{source}: action space {action_space}; pcpg needs a discrete action space "
            f"(Discrete(n))"
        )
    n_actions, start = int(action_space.n), int(action_space.start)
    raw_meta = dataset.storage.metadata
    ids, states, actions, rewards, success, lengths, styles, valids = [], [], [], [], [], [], [], []
    for ep in _episodes(dataset, dataset_id):
        where = f"{source}, episode {ep.id}"
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
        ids.append(int(ep.id))
        states.append(obs)
        actions.append(np.r_[act, -1])
        rewards.append(np.r_[np.asarray(ep.rewards, np.float64).reshape(-1), 0.0])
        success.append(bool(steps) and bool(ep.terminations[-1]) and not bool(ep.truncations[-1]))
        lengths.append(steps + 1)
        infos = ep.infos or {}
        styles.append(_styles(infos[STYLE_KEY], steps + 1, where) if STYLE_KEY in infos else None)
        valids.append(_valid_rows(infos, steps + 1, n_actions, where))

    if not ids:
        raise DataError(f"{source}: the dataset has no episodes")
    lengths_a = np.asarray(lengths)
    rows = int(lengths_a.sum())
    offsets = np.r_[0, np.cumsum(lengths_a)[:-1]]
    cols: dict[str, pa.Array] = {
        "trajectory": pa.array(np.repeat(np.asarray(ids, np.int64), lengths_a)),
        "t": pa.array(np.arange(rows, dtype=np.int64) - np.repeat(offsets, lengths_a)),
        "env": pa.array([env_name(dataset_id)] * rows, pa.string()),
    }
    all_states = np.concatenate(states)
    d = all_states.shape[1]
    for j in range(d):
        cols[f"s{j}"] = pa.array(all_states[:, j], pa.float32())
    cols["action"] = pa.array(np.concatenate(actions))
    cols["reward"] = pa.array(np.concatenate(rewards))
    cols["success"] = pa.array(np.repeat(np.asarray(success, bool), lengths_a))
    meta_styles = _metadata_styles(raw_meta, len(ids), source)
    if any(s is not None for s in styles):
        cols["style"] = pa.array(
            np.concatenate(
                [
                    s if s is not None else np.full(n, -1, np.int64)
                    for s, n in zip(styles, lengths, strict=True)
                ]
            )
        )
    elif meta_styles is not None:
        cols["style"] = pa.array(np.repeat(meta_styles, lengths_a))
    if any(v is not None for v in valids):
        check_action_memory(
            int(sum(lengths)), n_actions, source, f"its action space {action_space}"
        )
        mask = np.concatenate(
            [
                v if v is not None else np.ones((n, n_actions), bool)
                for v, n in zip(valids, lengths, strict=True)
            ]
        )
        cols["valid"] = pa.FixedSizeListArray.from_arrays(pa.array(mask.reshape(-1)), n_actions)
    del states, all_states  # the table holds its own copy

    pcpg_meta = raw_meta.get("pcpg") if isinstance(raw_meta.get("pcpg"), dict) else {}
    for key in ("feature_names", "action_names"):  # names pcpg wrote; anything else is not trusted
        value = pcpg_meta.get(key)
        if value is not None and not (
            isinstance(value, list) and all(isinstance(x, str) for x in value)
        ):
            raise DataError(
                f"{source}: metadata 'pcpg.{key}' is {reprlib.repr(value)}; expected a list of "
                f"names (strings), or no such key"
            )
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
        "total_episodes": len(ids),
        "total_steps": rows - len(ids),
        "minari_version": str(raw_meta.get("minari_version", "")),
        "pcpg": pcpg_meta,
    }
    return pa.table(cols), meta


# --------------------------------------------------------------------------- writing
def export_ids(dataset_id: str, envs: list[str]) -> dict[str, str]:
    """The Minari id of each environment: ``dataset_id`` itself for one environment; for several,
    one dataset each under the namespace of the id, e.g. ``pcpg/run-v0`` -> ``pcpg/run/<env>-v0``."""
    _check_id(dataset_id, need_version=True)
    if len(envs) == 1:
        return {envs[0]: dataset_id}
    match = MINARI_ID.fullmatch(dataset_id)
    base = f"{match['namespace']}/{match['name']}" if match["namespace"] else match["name"]
    ids = {env: f"{base}/{re.sub(r'[^A-Za-z0-9_-]', '_', env)}-v{match['version']}" for env in envs}
    if len(set(ids.values())) != len(ids):
        raise DataError(
            f"environments {', '.join(envs)} map to the same Minari ids ({sorted(ids.values())})"
        )
    return ids


def _episode_buffers(ds: Dataset) -> list[Any]:
    """One EpisodeBuffer per trajectory: T + 1 observations, T actions/rewards, per-step infos."""
    from minari.data_collector import EpisodeBuffer

    out = []
    for i in range(ds.n_trajectories):
        lo, hi = int(ds.offsets[i]), int(ds.offsets[i + 1])
        steps = hi - lo - 1
        done = np.zeros(steps, bool)
        term, trunc = done.copy(), done.copy()
        if steps:
            term[-1], trunc[-1] = bool(ds.success[i]), not bool(ds.success[i])
        out.append(
            EpisodeBuffer(
                id=i,
                observations=ds.states[lo:hi],
                actions=ds.actions[lo : hi - 1],
                rewards=ds.rewards[lo : hi - 1],
                terminations=term,
                truncations=trunc,
                # a list, not an array: Minari 0.5.4 cannot decode a 1-D ndarray info
                infos={STYLE_KEY: [int(ds.styles[i])] * (hi - lo), "valid": ds.valid[lo:hi]},
            )
        )
    return out


def _deferred_size(storage: Any) -> Any:
    """The same storage, but without the size refresh after every episode.

    Minari 0.5.4 re-walks every file of the dataset after each episode it writes to update
    ``dataset_size``: quadratic in episodes (2,000 episodes took 5 minutes). The caller sets
    ``dataset_size`` once at the end, to the same value.
    """
    base = type(storage)

    class DeferredSize(base):
        def get_size(self) -> float:
            return 0.0

    return DeferredSize(
        storage.data_path,
        storage.observation_space,
        storage.action_space,
        jpeg_encoding=storage.jpeg_encoding,
    )


def _build_prefix() -> str:
    """Temporary export roots are named ``<this>-<pid>-<random>.tmp``: which machine, which process."""
    return f".pcpg-minari-{socket.gethostname()}-"


def _remove_stale_builds(out_dir: Path) -> None:
    """Remove the temporary roots of exports on this machine whose process is gone (a SIGKILL
    skips the ``finally`` that removes them); another live export's, or another machine's, stay."""
    for folder in out_dir.glob(f"{_build_prefix()}*.tmp"):
        pid = folder.name.removeprefix(_build_prefix()).split("-", 1)[0]
        if not pid.isdigit():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            shutil.rmtree(folder, ignore_errors=True)
        except (PermissionError, OverflowError):  # alive, another user's; or no such pid at all
            continue


def write_minari(
    datasets: dict[str, Dataset], out_dir: Path, dataset_id: str, description: str | None = None
) -> dict[str, Path]:
    """Write pcpg datasets as Minari datasets under ``out_dir`` (use it as ``$MINARI_DATASETS_PATH``).

    One Minari dataset per environment (ids from :func:`export_ids`); episode ``i`` is
    trajectory ``i`` with ``terminations[-1] = success`` and ``truncations[-1] = not success``;
    ``infos`` carry ``style`` and ``valid`` per observation. Nothing is written when any target
    already exists. Returns ``{minari_id: folder}``.
    """
    import minari
    from gymnasium import spaces

    if not datasets:
        raise DataError("no datasets to export")
    out_dir = Path(out_dir)
    ids = export_ids(dataset_id, list(datasets))
    for mid in ids.values():
        if (out_dir / mid).exists():
            raise DataError(
                f"{out_dir / mid}: a Minari dataset {mid} already exists there (Minari never "
                f"overwrites); pick another --dataset-id or version, or delete it"
            )
    out_dir.mkdir(parents=True, exist_ok=True)
    # Built under a temporary root inside out_dir and renamed into place when every one is complete:
    # an interrupted export leaves no half dataset (Minari loaded one as valid, with 0 episodes, and
    # refused the rerun because it "already exists").
    _remove_stale_builds(out_dir)
    build = Path(
        tempfile.mkdtemp(dir=out_dir, prefix=f"{_build_prefix()}{os.getpid()}-", suffix=".tmp")
    )
    try:
        with datasets_root(build), warnings.catch_warnings():
            # Minari warns for every unset author/code_permalink/eval_env field: noise for an export.
            warnings.simplefilter("ignore", UserWarning)
            for env, ds in datasets.items():
                mid = ids[env]
                text = description or (
                    f"pcpg dataset {ds.domain}-{env}: {ds.n_trajectories} trajectories, "
                    f"state {ds.state_dim} features, {ds.n_actions} actions"
                )
                created = minari.create_dataset_from_buffers(
                    dataset_id=mid,
                    buffer=[],
                    observation_space=spaces.Box(-np.inf, np.inf, (ds.state_dim,), np.float32),
                    action_space=spaces.Discrete(ds.n_actions),
                    description=text,
                    data_format=DATA_FORMAT,
                )
                storage = _deferred_size(created.storage)
                storage.update_episodes(_episode_buffers(ds))
                storage.update_metadata(
                    {
                        "dataset_size": type(created.storage).get_size(storage),
                        "pcpg": {
                            "domain": ds.domain,
                            "env": env,
                            "feature_names": list(ds.feature_names),
                            "action_names": list(ds.action_names),
                        },
                    }
                )
        written = {}
        for mid in ids.values():
            (out_dir / mid).parent.mkdir(parents=True, exist_ok=True)
            if (out_dir / mid).exists():  # made by another process meanwhile
                raise DataError(
                    f"{out_dir / mid}: a Minari dataset {mid} already exists there (Minari never "
                    f"overwrites); pick another --dataset-id or version, or delete it"
                )
            (build / mid).rename(out_dir / mid)
            written[mid] = out_dir / mid
    finally:
        shutil.rmtree(build, ignore_errors=True)
    return written


# --------------------------------------------------------------------------- CLI
def find_dataset_folder(path: Path) -> Path:
    """A pcpg dataset folder (with manifest.json): ``path`` itself, or the cached data of a run's
    output folder (``runs/NAME/cache/data/<key>/``; the newest when there are several)."""
    path = Path(path)
    if (path / MANIFEST).is_file():
        return path
    if not path.is_dir():
        raise DataError(
            f"{path}: no such folder (expected a pcpg dataset folder or a run's output "
            f"folder runs/NAME)"
        )
    found = [
        m.parent
        for pattern in ("cache/data/*/" + MANIFEST, "data/" + MANIFEST, "data/*/" + MANIFEST)
        for m in path.glob(pattern)
        if m.is_file()
    ]
    if not found:
        raise DataError(
            f"{path}: neither a pcpg dataset folder ({MANIFEST}) nor a run's output folder "
            f"with cached data (cache/data/<key>/{MANIFEST})"
        )
    return max(found, key=lambda p: (p / MANIFEST).stat().st_mtime)


def cli_export_minari(args: argparse.Namespace) -> None:
    """``pcpg export minari RUN_OR_DATA --out DIR [--dataset-id ID]``."""
    from pcpg_dist.common.run_folders import check_outside_run

    check_outside_run(Path(args.out))
    folder = find_dataset_folder(Path(args.source))
    datasets = load_datasets(folder)
    source = Path(args.source).resolve()
    name = re.sub(r"[^A-Za-z0-9_-]", "_", source.name).strip("_") or "data"
    dataset_id = args.dataset_id or f"pcpg/{name}-v0"
    out = Path(args.out)
    ids = export_ids(dataset_id, list(datasets))
    written = write_minari(datasets, out, dataset_id)
    print(f"read {folder}")
    for env, mid in ids.items():
        ds = datasets[env]
        print(
            f"wrote {written[mid]}  (Minari id {mid}: {ds.n_trajectories} episodes, "
            f"{ds.n_rows - ds.n_trajectories} steps, state {ds.state_dim}, {ds.n_actions} actions)"
        )
    print(
        f"load with {ENV_VAR}={out.resolve()} and minari.load_dataset(ID), or in pcpg as minari:ID"
    )
