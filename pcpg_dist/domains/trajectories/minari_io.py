"""Minari datasets <-> pcpg: what reading and writing share, and writing pcpg datasets as Minari's.

Reading (``minari:DATASET_ID`` in a config) is :mod:`.minari_read`'s; both sides agree here on the
dataset ids, the folder Minari reads (``$MINARI_DATASETS_PATH``) and the per-step info keys.

Both check the folders they touch as every input is (:mod:`pcpg_dist.common.inputs`): a dataset
folder before Minari reads a byte of it (:func:`check_local_dataset`), the ``--out`` folder before
the export writes into it.

Writing (``pcpg export minari``): one Minari dataset per environment, observation space
``Box(-inf, inf, (d,), float32)``, action space ``Discrete(n_actions)``, per-step infos ``style``
and ``valid``, so that reading it back gives the same step table.
"""

from __future__ import annotations

import argparse
import contextlib
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

from pcpg_dist.common import inputs, memory
from pcpg_dist.common.errors import DataError
from pcpg_dist.dataset import MANIFEST, Dataset, load_datasets
from pcpg_dist.domains.trajectories.settings import MINARI_ID, minari_id_problem

ENV_VAR = "MINARI_DATASETS_PATH"
STYLE_KEY = "style"
VALID_KEYS = ("valid", "action_mask")
DATA_FORMAT = "arrow"  # installed with minari[arrow]; hdf5 would need h5py
# what pcpg reads: the data files' kinds and first bytes (Minari's hdf5 needs h5py, not installed)
FORMATS = {"arrow": ("an Arrow IPC file", b"ARROW1"), "parquet": ("a Parquet file", b"PAR1")}
META_BYTES = 16 << 20  # a metadata.json: spaces and names; an image space's bounds take ~1 MB


def env_name(dataset_id: str) -> str:
    """The ``env`` value (a folder name) of a Minari dataset: its id with unsafe characters -> '_'."""
    from pcpg_dist.domains.trajectories.table_files import safe_env_name

    return safe_env_name(dataset_id)


def check_id(dataset_id: str, need_version: bool = False) -> None:
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


# --------------------------------------------------------------------------- checking a dataset
def check_local_dataset(path: Path, dataset_id: str) -> dict:
    """The local Minari dataset folder ``path``, checked before Minari reads a byte of it: its
    ``metadata.json`` (size, nesting, the keys Minari reads, ``total_episodes`` against the
    episode folders present) and every episode's data file (a regular file inside its folder,
    readable, of the dataset's format; all of them within half this machine's memory). Returns
    the metadata; one :class:`DataError` line naming the file or key otherwise. (Minari's own
    failures were tracebacks, and an episode file that read as nothing dropped the episode.)"""
    source = f"minari:{dataset_id}:"
    data = inputs.input_folder(path / "data", f"{source} data folder", folder=path)
    meta_file = data / "metadata.json"
    meta = inputs.input_json(meta_file, source, folder=data, max_bytes=META_BYTES)
    where = f"{source} {meta_file}:"
    for key in ("total_episodes", "total_steps"):
        value = meta.get(key)
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise DataError(f"{where} {_shown(meta, key)}; expected a whole number >= 0")
    if not isinstance(meta.get("data_format"), str) or meta["data_format"] not in FORMATS:
        raise DataError(
            f"{where} {_shown(meta, 'data_format')}; pcpg reads Minari datasets stored as "
            f"'arrow' or 'parquet'"
        )
    for key in ("observation_space", "action_space", "env_spec", "eval_env_spec"):
        value = meta.get(key)
        if value is None and key.endswith("_space"):
            raise DataError(
                f"{where} {_shown(meta, key)}; pcpg reads the spaces a dataset stores, and never "
                f"builds the environment its env_spec names"
            )
        if value is not None and not isinstance(value, str):
            raise DataError(f"{where} {_shown(meta, key)}; expected JSON text (a string)")
        if value is not None:
            inputs.json_text(value, f"{where} '{key}'")
    for key in ("dataset_id", "minari_version"):
        if not isinstance(meta.get(key), str):
            raise DataError(f"{where} {_shown(meta, key)}; expected a string")
    _check_episode_folders(data, meta["total_episodes"], source, where)
    limit, total = memory.machine_memory() // 2, 0
    for i in range(meta["total_episodes"]):
        total += _check_episode(data / str(i), data, meta["data_format"], source, limit)
    if total > limit:
        raise DataError(
            f"{source} the episode files under {data} hold {memory.gib(total)}, more than half of "
            f"this machine's {memory.gib(memory.machine_memory())} (pcpg holds a dataset in memory)"
        )
    return meta


def _shown(meta: dict, key: str) -> str:
    value = meta.get(key)
    if key not in meta or value is None:
        return f"'{key}' is missing"
    return f"'{key}' is {value:,}" if type(value) is int else f"'{key}' is {reprlib.repr(value)}"


def _check_episode_folders(data: Path, n: int, source: str, where: str) -> None:
    """Exactly the folders ``0..n-1``: Minari reads those, and nothing counts whether each gave an
    episode (``n = 10**12`` was a 7.28 TiB ``np.arange``)."""
    names = [p.name for p in inputs.entries(data, f"{source} episode folder", dirs=True)]
    ids = sorted(int(x) for x in names if x.isascii() and x.isdigit() and str(int(x)) == x)
    missing = next((i for i, got in enumerate(ids) if i != got), len(ids))
    if missing < n:
        raise DataError(
            f"{source} unreadable episode data (no such file {data / str(missing)}; "
            f"{data / 'metadata.json'} says 'total_episodes' is {n:,}, and {len(ids):,} episode "
            f"folders are present)"
        )
    if len(ids) > n:
        raise DataError(
            f"{where} 'total_episodes' is {n:,}, but {data} holds {len(ids):,} episode folders "
            f"({data / str(ids[n])} is one more); no episode is left out: correct total_episodes, "
            f"or remove the extra folders"
        )


def _check_episode(folder: Path, data: Path, fmt: str, source: str, limit: int) -> int:
    """One episode folder: one data file of format ``fmt`` (a regular file inside it, readable,
    at most ``limit`` bytes), besides its metadata.json. Returns the data file's size."""
    what = f"{source} episode"
    inputs.input_folder(folder, what, folder=data)
    ignored = ("_", ".", "metadata.json")  # what Minari's Arrow scan skips
    sub = [d for d in inputs.entries(folder, what, dirs=True) if not d.name.startswith(ignored)]
    if sub:
        raise DataError(
            f"{what} {sub[0]}: a folder inside an episode folder (Minari would read its files "
            f"into the episode); an episode folder holds one data file and metadata.json"
        )
    files = [f for f in inputs.entries(folder, what) if not f.name.startswith(ignored)]
    if len(files) != 1:
        found = f"{len(files)} data files ({', '.join(f.name for f in files[:3])})"
        raise DataError(
            f"{what} {folder}: {found if files else 'no data file'}; Minari stores one per "
            f"episode, and reads a folder without one as no episode at all"
        )
    kind, magic = FORMATS[fmt]
    path = inputs.input_file(files[0], what, folder=folder, max_bytes=limit)
    try:
        with open(path, "rb") as f:
            head = f.read(len(magic))
    except OSError as e:
        raise DataError(f"{what} {path}: unreadable ({e.strerror or e})") from None
    if head != magic:
        raise DataError(
            f"{what} {path}: not {kind} (it starts {head!r}, not {magic!r}); the dataset's "
            f"data_format is '{fmt}'"
        )
    return path.stat().st_size


# --------------------------------------------------------------------------- writing
def export_ids(dataset_id: str, envs: list[str]) -> dict[str, str]:
    """The Minari id of each environment: ``dataset_id`` itself for one environment; for several,
    one dataset each under the namespace of the id, e.g. ``pcpg/run-v0`` -> ``pcpg/run/<env>-v0``."""
    check_id(dataset_id, need_version=True)
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


def _target(out_dir: Path, mid: str) -> Path:
    """Where the dataset ``mid`` goes: nothing there yet, and no link on the way leading out of
    ``out_dir`` (``DIR/pcpg -> elsewhere`` put the dataset elsewhere, exit 0)."""
    target = inputs.write_target(out_dir, mid, "--out")
    if os.path.lexists(target):
        raise DataError(
            f"{target}: a Minari dataset {mid} already exists there (Minari never overwrites); "
            f"pick another --dataset-id or version, or delete it"
        )
    return target


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
    out_dir = inputs.writable_folder(Path(out_dir), "--out")
    ids = export_ids(dataset_id, list(datasets))
    for mid in ids.values():
        _target(out_dir, mid)
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
            _target(out_dir, mid).parent.mkdir(parents=True, exist_ok=True)
            (build / mid).rename(_target(out_dir, mid))  # checked again: another process meanwhile
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
