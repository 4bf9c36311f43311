"""The data a run used, as MLflow dataset inputs: the runs table's Dataset column, filters and
comparisons show them (MLflow's own lineage), beside the files of the run's ``summary/run.json``.

A config's data is logged twice, as two datasets: the data itself (context ``training``:
clustering, ranking and BC read its training split) and its held-out split (context
``evaluation``: every seed's agents are evaluated on it). The digest is pcpg's input key of
the data (:func:`pcpg_dist.pipeline.declared.data_keys`: the domain's settings, seed and the
content of every file it reads, without pcpg's code version), so one log shows one digest
across runs and pcpg versions, and a changed file a new one; `pcpg reproduce` compares the same
key before rerunning. The source says where the data comes from (a file's URI, a Minari id, or
the generator's settings and seed; :meth:`pcpg_dist.domains.base.Domain.data_source`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

from pcpg_dist.common.keys import content_key
from pcpg_dist.tracking.connection import _retry

CONTEXT_TAG = "mlflow.data.context"  # MLflow's input tag for a dataset's role in a run


@dataclass(frozen=True)
class DataInput:
    """One dataset input of a run: what MLflow stores and the UI shows."""

    name: str
    digest: str
    source_type: str
    source: str  # JSON text
    context: str  # "training" or "evaluation"
    profile: str | None = None  # JSON text: environments, trajectories and steps (the UI shows it)

    def as_dict(self) -> dict[str, str]:
        return dict(self.__dict__)


def data_inputs(cfg, ikey: str, units: list | None = None) -> list[DataInput]:
    """The training data and its held-out split of the config whose data has input key ``ikey``;
    with its evaluation ``units`` (:class:`~pcpg_dist.domains.base.Unit`), each profiled
    (environments, trajectories, steps)."""
    from pcpg_dist.domains.sources import data_source

    found = data_source(cfg)
    held_out = {"test_fraction": cfg.ranking.test_fraction, "split_seed": cfg.ranking.split_seed}
    return [
        DataInput(
            found["name"],
            ikey,
            found["type"],
            _text(found["source"]),
            "training",
            _profile(units, "train_idx"),
        ),
        DataInput(
            f"{found['name']} · held-out {cfg.ranking.test_fraction:g}",
            content_key(ikey, held_out),
            found["type"],
            _text({**found["source"], "held_out": held_out}),
            "evaluation",
            _profile(units, "test_idx"),
        ),
    ]


def log_data_inputs(client, run_id: str, inputs: list[DataInput | dict]) -> None:
    """Log ``inputs`` on ``run_id``; MLflow keeps one input per (name, digest) and run, so
    logging again (a rerun, a resumed run) adds nothing."""
    from mlflow.entities import Dataset, DatasetInput, InputTag

    if not inputs:
        return
    batch = [
        DatasetInput(
            Dataset(
                name=i.name,
                digest=i.digest,
                source_type=i.source_type,
                source=i.source,
                profile=i.profile,
            ),
            tags=[InputTag(key=CONTEXT_TAG, value=i.context)],
        )
        for i in (DataInput(**i) if isinstance(i, dict) else i for i in inputs)
    ]
    _retry(client.log_inputs, run_id, datasets=batch)


def _text(source: dict) -> str:
    return json.dumps(source, sort_keys=True)


def _profile(units: list | None, part: str) -> str | None:
    """The units' trajectories in ``part`` (their training or held-out positions), counted."""
    if not units:
        return None
    counts = {"environments": len(units), "trajectories": 0, "steps": 0}
    for u in units:
        idx = getattr(u, part)
        lengths = u.dataset.offsets[idx + 1] - u.dataset.offsets[idx]
        counts["trajectories"] += len(idx)
        counts["steps"] += int(lengths.sum())
    return _text(counts)
