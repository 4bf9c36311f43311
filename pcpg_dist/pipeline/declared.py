"""The pipeline, declared once as data: which stages run, in which order, what each runs per
job, what names its results in the cache, and what it asks of the machine.

Every entry point runs this one declaration: `pcpg run` and `pcpg sweep` all of it
(:func:`pcpg_dist.orchestration.runner.run_points`), `pcpg cluster` up to ``cluster``, a tuning
trial all of it in one process (:func:`pcpg_dist.pipeline.units.run_unit`). A runner executes a
stage's jobs through an executor (Ray, or this process); tracking, reports and exports hang on the
runner as hooks. Kedro's ``pipeline``/``node`` with swappable runners is the model.

A stage's task is named as ``"module:function"`` and imported when the stage runs, so reading the
declaration imports no stage code (and a test can replace one task by patching its module).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pcpg_dist.common.keys import content_key
from pcpg_dist.domains import contract

CODE_VERSION = (
    "2"  # bump when a stage's numbers or files change for the same config (2: bool valid masks)
)
CLUSTER_VERSION = "2"  # bump when only Step A's files change (2: result.json holds the margins)
EVAL_VERSION = "3"  # bump when only the evaluation's metrics or tables change (3: cluster_style, kept length in steps)


@dataclass(frozen=True)
class Stage:
    """One stage of the pipeline.

    ``name`` names its cache folder, its timing and ``--until``; ``counter`` its count of jobs
    computed in ``run.json``; ``task`` is what one job runs (``None``: the driver does the
    stage itself, as the data stage does); ``device`` is the config section whose ``device``
    decides whether its jobs ask Ray for a GPU share (``""``: never)."""

    name: str
    description: str
    counter: str
    task: str | None = None
    device: str = ""

    def function(self) -> Callable[..., Any]:
        """The stage's task, imported now (a patched module attribute is honoured)."""
        if self.task is None:
            raise ValueError(f"stage {self.name} runs in the driver and has no task")
        module, _, attribute = self.task.partition(":")
        return getattr(importlib.import_module(module), attribute)


DATA = Stage("generate", "Data", "data")
CLUSTER = Stage(
    "cluster",
    "Step A: clustering",
    "clustering",
    "pcpg_dist.pipeline.tasks:cluster_task",
    "clustering",
)
TRAIN = Stage(
    "train", "Step C: BC groups", "train_groups", "pcpg_dist.pipeline.tasks:train_task", "bc"
)
EVALUATE = Stage("evaluate", "Evaluation", "evaluations", "pcpg_dist.pipeline.tasks:evaluate_task")

#: the stages in the order they run; Step B (ranking and cutting cells) plans TRAIN's jobs
PIPELINE: tuple[Stage, ...] = (DATA, CLUSTER, TRAIN, EVALUATE)
STAGES = tuple(s.name for s in PIPELINE)


def upto(name: str) -> tuple[Stage, ...]:
    """The stages from the first through ``name``."""
    if name not in STAGES:
        raise ValueError(f"no stage {name!r}; the stages are {', '.join(STAGES)}")
    return PIPELINE[: STAGES.index(name) + 1]


# --------------------------------------------------------------------------- content keys
def data_keys(cfg) -> tuple[str, str]:
    """``(data key, input key)`` from one reading of what the domain says identifies its data
    (settings, file contents, seed; a log is hashed once). The data key, with pcpg's code
    version, names the data in the cache; the input key, without it, is what ``run.json``
    records for ``pcpg reproduce`` to tell "the inputs changed" apart from "the code changed"."""
    parts = contract.data_key(cfg)
    return content_key(CODE_VERSION, *parts), content_key(*parts)


def data_key(cfg) -> str:
    """Content key of the data (see :func:`data_keys`)."""
    return data_keys(cfg)[0]


def input_key(cfg) -> str:
    """Key of the data stage's inputs (see :func:`data_keys`)."""
    return data_keys(cfg)[1]


def cluster_key(dkey: str, env: str, cfg, note: Any, digest: str) -> str:
    """One unit's clustering: the data, the unit, the settings and seed, and the digest of what
    the clusterer reads (a domain may derive it from any setting: Mario's valid mask comes from
    the training episodes, so from the split)."""
    return content_key(
        CODE_VERSION, CLUSTER_VERSION, dkey, env, cfg.clustering, cfg.seed, note, digest
    )


def train_key(ckey: str, cfg, cell_keys: list[str], base_keys: list[str]) -> str:
    """One group of cells: its clustering, the settings that shape its cells, the cells."""
    return content_key(
        CODE_VERSION,
        ckey,
        cfg.ranking,
        cfg.bc,
        cfg.evaluation.corruption_levels,
        cfg.evaluation.corruption_ps,
        cell_keys,
        base_keys,
    )


def evaluate_key(train_keys: list[str], cfg) -> str:
    """One unit's evaluation: its trained groups, the evaluation and ranking settings, and what
    else the domain says moves its evaluation (a rollout env's settings; for most domains
    nothing, and then the key is what it was before the domain could say)."""
    extra = contract.evaluation_key(cfg)
    return content_key(
        CODE_VERSION,
        EVAL_VERSION,
        train_keys,
        cfg.evaluation,
        cfg.ranking,
        *([extra] if extra else []),
    )
