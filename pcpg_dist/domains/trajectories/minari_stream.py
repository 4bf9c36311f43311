"""A local Minari dataset (``minari:DATASET_ID``) for the streamed pipeline: what it needs to
know from the dataset's metadata alone (:func:`minari_stream_source`), and the episodes read a
range at a time inside the engine's block tasks (:func:`read_episodes`), checked and flattened as
:func:`~pcpg_dist.domains.trajectories.minari_read.read_minari` does for the whole dataset.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from pcpg_dist.common.errors import DataError, first_line
from pcpg_dist.domains.base import StreamSource
from pcpg_dist.domains.trajectories.minari_io import env_name
from pcpg_dist.domains.trajectories.minari_read import _Episodes, _load, _metadata_styles
from pcpg_dist.domains.trajectories.stream_meta import check_stream_score

STEPS_PER_PART = 250_000  # about this many steps of episodes a block task reads at once


def minari_stream_source(settings, name: str) -> StreamSource | None:
    """The dataset as a :class:`StreamSource` (its episodes in parts of about
    :data:`STEPS_PER_PART` steps), or None when ``stream: auto`` and it is small."""
    from gymnasium import spaces
    from minari.storage import get_dataset_path

    source, dataset_id = settings.path, settings.path.removeprefix("minari:")
    dataset, checked = _load(dataset_id)
    episodes, steps = checked["total_episodes"], checked["total_steps"]
    rows = steps + episodes  # one row per observation: T + 1 an episode
    if settings.stream == "auto" and rows <= settings.stream_above_steps:
        return None
    check_stream_score(settings)
    if not episodes:
        raise DataError(f"{source}: the dataset has no episodes")
    data = str(Path(get_dataset_path(dataset_id)) / "data")  # read there by the block tasks
    per_part = max(1, STEPS_PER_PART * episodes // max(rows, 1))
    parts = tuple(
        {"dataset": dataset_id, "data": data, "lo": lo, "hi": min(episodes, lo + per_part)}
        for lo in range(0, episodes, per_part)
    )
    return StreamSource(
        name=name,
        files=(data,),
        states=tuple(f"s{j}" for j in range(spaces.flatdim(dataset.observation_space))),
        n_actions=int(dataset.action_space.n),
        steps=rows,
        optional=("reward", "style"),  # style -1 (unknown) where the data has none
        score=settings.score,
        max_epochs=settings.stream_epochs,
        parts=parts,
        read_part=read_episodes,
    )


def read_episodes(part: dict[str, Any], columns: list[str]) -> Iterator[pa.Table]:
    """Episodes ``part["lo"]`` to ``part["hi"] - 1`` of the local Minari dataset ``part["dataset"]``
    (its data folder ``part["data"]``: a worker need not share the driver's environment) as
    step-table rows of ``columns``: checked episode by episode (one line naming the episode),
    observations flattened to float32 ``s0..s{d-1}``, the last row of each episode action -1."""
    from minari import MinariDataset

    dataset_id = str(part["dataset"])
    source = f"minari:{dataset_id}"
    errors = (ValueError, KeyError, TypeError, OSError, AssertionError, pa.ArrowException)
    try:
        dataset = MinariDataset(str(part["data"]))
        indices = np.arange(int(part["lo"]), int(part["hi"]))
        obs_space, action_space = dataset.observation_space, dataset.action_space
        n_actions, start = int(action_space.n), int(action_space.start)
        eps = _Episodes()
        for ep in dataset.iterate_episodes(episode_indices=indices.tolist()):
            eps.add(ep, obs_space, action_space, n_actions, start, f"{source}, episode {ep.id}")
        meta_styles = _metadata_styles(dataset.storage.metadata, dataset.total_episodes, source)
    except errors as e:
        raise DataError(f"{source}: unreadable episode data ({first_line(e)})") from None
    cols, _ = eps.columns(env_name(dataset_id))
    eps.add_styles(cols, None if meta_styles is None else meta_styles[indices])
    if "style" not in cols:
        cols["style"] = pa.array(np.full(len(cols["action"]), -1, np.int64))
    yield pa.table({c: cols[c] for c in columns})
