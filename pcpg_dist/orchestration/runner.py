"""The runner: the declared pipeline (:mod:`pcpg_dist.pipeline.declared`) over one or more
points, every stage's jobs through one executor, every result in the content-keyed cache.

Every unit of work has a content key (its config slice + its inputs' keys) and a cache folder
(:mod:`pcpg_dist.orchestration.cache`); a finished unit is never recomputed, so rerunning the same
command after Ctrl-C or a killed process continues where it stopped and ends with the same numbers.

Several configs (the points of a sweep) run together stage by stage: their jobs interleave on the
cluster and a unit that two points share by key (same data, same clustering, same trained cells)
runs once. No shared disk is assumed: jobs take their inputs as arguments and return their
results as values; the driver is the only process that writes the cache. What happens around the
stages (the summary, the report, MLflow) is the hooks' (:mod:`pcpg_dist.orchestration.hooks`):
the runner imports none of it.
"""

from __future__ import annotations

import contextlib
import functools
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pcpg_dist.common.file_bytes import files_of
from pcpg_dist.common.files import confined
from pcpg_dist.common.keys import content_key
from pcpg_dist.common.progress import progress_bar
from pcpg_dist.common.run_folders import check_unit_name
from pcpg_dist.dataset import Dataset, content_digest
from pcpg_dist.domains import contract
from pcpg_dist.orchestration import points as data
from pcpg_dist.orchestration.cache import Cache
from pcpg_dist.orchestration.executors import Executor, RayExecutor, nbytes
from pcpg_dist.orchestration.hooks import NoHooks, RunHooks
from pcpg_dist.orchestration.points import Outcome, Point, clusters_of
from pcpg_dist.orchestration.resources import bc_gpus, cluster_gpus, unit_cluster_gpus
from pcpg_dist.pipeline import declared
from pcpg_dist.pipeline.declared import CLUSTER, EVALUATE, TRAIN, Stage

#: the most threads :meth:`Batch.spread` gives one job (torch's gain flattens beyond)
MAX_SPREAD_THREADS = 4

# fields of a config that cannot change its evaluation units (dataset, split, what Step A sees)
NOT_IN_UNITS = {"name", "clustering", "bc", "evaluation", "runner", "tuning", "seeds", "sweep"}


@dataclass
class Batch:
    """The points running together, and what their stages have done so far."""

    points: list[Point]
    cache: Cache
    executor: Executor
    show_progress: bool
    times: dict[str, float] = field(default_factory=dict)
    computed: dict[str, int] = field(default_factory=dict)
    clusters: dict[str, dict] = field(default_factory=dict)

    @property
    def threads(self) -> int:
        return max(p.cfg.runner.cpus_per_task for p in self.points)

    def spread(self, n_jobs: int) -> int:
        """Threads for each of ``n_jobs`` jobs that cannot be cut finer (one unit's clustering):
        ``runner.cpus_per_task``, or where the jobs are fewer than the CPUs, a share of every CPU
        (at most what the smallest worker has). One log's clustering ran on one of two cores."""
        share = self.executor.slots(1) // max(1, n_jobs)
        return max(self.threads, min(share, self.executor.widest(), MAX_SPREAD_THREADS))

    def run_jobs(
        self,
        stage: Stage,
        jobs: dict[str, tuple],
        save: Callable[[str, Any], None],
        gpus: dict[str, float] | None = None,
        description: str | None = None,
        threads: int | None = None,
    ) -> int:
        """Run one job of ``stage`` per key of ``jobs`` (keys shared by several points run once);
        ``save`` each result as it comes. ``gpus``: what each key's job asks for (none where
        missing); ``threads``: the CPUs each asks for (default ``runner.cpus_per_task``)."""
        keys = list(jobs)
        self.executor.map(
            stage.function(),
            [jobs[k] for k in keys],
            description or stage.description,
            num_cpus=threads or self.threads,
            on_result=lambda i, res: save(keys[i], res),
            show_progress=self.show_progress,
            num_gpus=[(gpus or {}).get(k, 0.0) for k in keys],
        )
        return len(keys)


def run_points(
    points: list[Point],
    cache_root: Path,
    *,
    hooks: RunHooks | None = None,
    executor: Executor | None = None,
    show_progress: bool = True,
    until: str = EVALUATE.name,
) -> list[Any]:
    """Run (or resume) the pipeline through ``until`` for several configs together, stage by
    stage, sharing units by content key; returns what ``hooks.finished`` returns (without hooks,
    each point's :class:`~pcpg_dist.orchestration.points.Outcome`).

    One process at a time works on a cache: a second `pcpg run` of the same folder waits for the
    first, then finds everything done.
    """
    from filelock import FileLock, Timeout

    cache_root = Path(cache_root)
    # folders this call creates: removed again if the input turns out bad (nothing half-written)
    created = [d for d in (cache_root.parent, *cache_root.parent.parents) if not d.exists()]
    cache_root.parent.mkdir(parents=True, exist_ok=True)
    lock = FileLock(str(cache_root) + ".lock")
    try:
        lock.acquire(timeout=0.5)
    except Timeout:
        from pcpg_dist.common.progress import console

        console.print(f"waiting for another pcpg process working on {cache_root.parent} ...")
        lock.acquire()
    batch = Batch(points, Cache(cache_root), executor or RayExecutor(), show_progress)
    try:
        return _run_stages(batch, hooks or NoHooks(), declared.upto(until))
    except BaseException:  # bad input, an OSError, Ctrl-C: whatever it was, leave no empty folders
        if created and not cache_root.exists():  # failed before anything was cached
            Path(lock.lock_file).unlink(missing_ok=True)
            for d in created:
                with contextlib.suppress(OSError):
                    d.rmdir()
        raise
    finally:
        lock.release()


def _run_stages(batch: Batch, hooks: RunHooks, stages: tuple[Stage, ...]) -> list[Any]:
    """The declared stages in order: the data in the driver, then each stage's jobs."""
    most_gpus = batch.executor.most_gpus()
    for p in batch.points:
        batch.executor.check(p.cfg.runner.cpus_per_task)
        # a GPU setting no node can serve fails here
        p.gpus = (cluster_gpus(p.cfg, most_gpus), bc_gpus(p.cfg, most_gpus))
    batch.computed.update({s.counter: 0 for s in declared.PIPELINE})
    t0 = time.perf_counter()
    _load_data(batch)  # a bad input file fails here, before any MLflow run or cache entry exists
    batch.times[declared.DATA.name] = time.perf_counter() - t0
    try:
        hooks.started(batch.points)  # inside: an interrupt here still marks the runs made so far
        for stage in stages[1:]:
            t0 = time.perf_counter()
            STAGE_DRIVERS[stage.name](batch, stage)
            batch.times[stage.name] = time.perf_counter() - t0
        outcomes = [
            Outcome(
                p,
                batch.cache,
                batch.clusters,
                dict(batch.times),
                batch.computed,
                len(batch.points),
                batch.executor,
            )
            for p in batch.points
        ]
        return hooks.finished(outcomes)
    except BaseException:
        hooks.failed(batch.points)
        raise


def _load_data(batch: Batch) -> None:
    """Each distinct dataset loaded or generated once, each distinct unit shared once."""
    datas: dict[str, dict[str, Dataset]] = {}
    unit_sets: dict[str, tuple[dict, dict, dict]] = {}
    for p in batch.points:
        p.dkey, p.ikey = declared.data_keys(p.cfg)
        if p.dkey not in datas:
            batch.computed["data"] += batch.cache.done("data", p.dkey) is None
            datas[p.dkey] = data.load_or_generate(
                p.cfg, batch.cache, batch.show_progress, p.dkey, batch.executor.fan_out
            )[0]
        ukey = content_key(p.dkey, p.cfg.model_dump(mode="json", exclude=NOT_IN_UNITS))
        if ukey not in unit_sets:
            unit_sets[ukey] = _unit_set(p, datas[p.dkey], batch.executor)
        p.units, p.refs, p.digests = unit_sets[ukey]
    # one task holds a unit, its copies in the stage's arrays, and a torch runtime (~600 MB)
    largest = max((nbytes(u.dataset) for p in batch.points for u in p.units.values()), default=0)
    batch.executor.check(batch.threads, 6e8 + 8.0 * largest)


def _unit_set(
    p: Point, datasets: dict[str, Dataset], executor: Executor
) -> tuple[dict, dict, dict]:
    """A point's evaluation units, each put once where every job can read it, and the digest of
    what each unit's clusterer reads."""
    from pcpg_dist.stages.ranking import check_margins_come

    units = {u.name: u for u in contract.units(p.cfg, datasets)}
    data.warn_partial_styles(list(units.values()))
    for name in units:
        confined(p.out, name, "unit name")  # unit names become folder and run names
        check_unit_name(name)
    check_margins_come(p.cfg, [u.clustered for u in units.values()])
    refs = {n: executor.put(u) for n, u in units.items()}
    return units, refs, {n: content_digest(u.clustered) for n, u in units.items()}


# --------------------------------------------------------------------------- Step A
def _cluster(batch: Batch, stage: Stage) -> None:
    """One clustering per (data, environment, clustering settings)."""
    jobs: dict[str, tuple] = {}
    gpus: dict[str, float] = {}
    for p in batch.points:
        for e, u in p.units.items():
            p.ckeys[e] = k = declared.cluster_key(
                p.dkey, e, p.cfg, u.cluster_input_note, p.digests[e]
            )
            if k not in jobs and batch.cache.done("cluster", k) is None:
                jobs[k] = (p.refs[e], p.cfg.clustering, p.cfg.seed)
                gpus[k] = unit_cluster_gpus(p.gpus[0], p.cfg.clustering, u.clustered)
    threads = batch.spread(len(jobs)) if not any(gpus.values()) else batch.threads
    jobs = {k: (*job, threads) for k, job in jobs.items()}

    def save(key: str, res: dict) -> None:
        files = {
            "result.json": json.dumps(
                {k: res[k] for k in ("labels", "margins", "metrics")}
            ).encode(),
            **{f"model/{n}": b for n, b in res["model"].items()},
        }
        batch.cache.store("cluster", key, files, {"stage": "cluster"})

    batch.computed[stage.counter] = batch.run_jobs(stage, jobs, save, gpus, threads=threads)
    batch.clusters.update(
        {
            k: batch.cache.read_json("cluster", k, "result.json")
            for p in batch.points
            for k in p.ckeys.values()
        }
    )


# --------------------------------------------------------------------------- Steps B + C
def _train(batch: Batch, stage: Stage) -> None:
    """Rank every unit and cut its cells into groups (Step B: the cells' specs here, each
    group's rows built in its training task), train the groups. Where ``bc.init`` resolves to
    no_clustering (auto: by the unit's clustering verdict) a second round trains the other
    cells, each from the first round's No Clustering agent."""
    from pcpg_dist.pipeline.units import plan_unit_specs
    from pcpg_dist.stages.bc import finetune_config, split_for_init
    from pcpg_dist.stages.clustering.confidence import verdict_of

    later: list[tuple[Point, str, list, tuple, list[str]]] = []
    jobs: dict[str, tuple] = {}

    def slots(p: Point) -> int:  # one unit's cells spread over every CPU the cluster offers
        return batch.executor.slots(p.cfg.runner.cpus_per_task)

    # the ranking runs here (scores and thresholds); the rows of the cells, the costly part of
    # Step B (on 40,000 trajectories ~15 s), are built by the training tasks
    total = sum(len(p.units) for p in batch.points)
    with progress_bar("Step B: ranking", total=total, enabled=batch.show_progress) as advance:
        for p in batch.points:
            for e, u in p.units.items():
                clustered = batch.clusters[p.ckeys[e]]
                labels, margins = clusters_of(clustered)
                specs = plan_unit_specs(u, labels, p.cfg, margins=margins)
                said = verdict_of(clustered.get("metrics", {}), p.cfg.clustering.k)
                first, rest = split_for_init(specs, p.cfg.bc, said.doubts_styles)
                plan = (p.refs[e], labels, margins, p.cfg)
                _add_groups(p, e, first, plan, batch.cache, jobs, p.cfg.bc, [], slots=slots(p))
                if rest:
                    later.append((p, e, rest, plan, p.train_keys(e)))
                advance()

    def save(key: str, res: dict) -> None:
        batch.cache.store("train", key, res["files"], {"stage": "train", "cells": res["cells"]})

    def gpus() -> dict[str, float]:
        return {k: p.gpus[1] for p in batch.points for _, k, _ in p.groups}

    batch.computed[stage.counter] = batch.run_jobs(stage, jobs, save, gpus())
    if later:
        jobs = {}
        for p, e, rest, plan, base_keys in later:
            # the No Clustering agents' files, read only when some group of this unit is not
            # cached yet; each task reads them itself (the driver loads no tensors, no torch)
            base = functools.cache(lambda keys=tuple(base_keys): trained_files(batch.cache, keys))
            bc_cfg = finetune_config(p.cfg.bc)
            _add_groups(p, e, rest, plan, batch.cache, jobs, bc_cfg, base_keys, base, slots(p))
        batch.computed[stage.counter] += batch.run_jobs(
            stage, jobs, save, gpus(), f"{stage.description} from No Clustering"
        )


def _add_groups(
    p: Point,
    unit: str,
    cells: list,
    plan: tuple,
    cache: Cache,
    jobs: dict[str, tuple],
    bc_cfg,
    base_keys: list[str],
    base: Callable[[], Any] | None = None,
    slots: int = 1,
) -> None:
    """Cut ``cells`` (their specs) into groups of at most ``runner.group_size``, and into at
    least ``slots`` groups (the jobs the cluster runs at once) where there are cells enough, so
    one unit's training uses every CPU; each group is a content-keyed training job (unless
    cached) that builds its cells from ``plan`` (the unit, its labels and margins, the config).
    A cell trains the same in any group (tests/stages/test_bc.py::test_batched_equals_alone).
    With ``base`` (returns the No Clustering agents' files) each cell starts from its own."""
    cfg = p.cfg
    size = max(1, min(cfg.runner.group_size, -(-len(cells) // max(1, slots))))
    for g in range(0, len(cells), size):
        chunk = cells[g : g + size]
        key = declared.train_key(p.ckeys[unit], cfg, [c.key for c in chunk], base_keys)
        p.groups.append((unit, key, chunk))
        if key not in jobs and cache.done("train", key) is None:
            jobs[key] = (
                *plan,
                [c.key for c in chunk],
                bc_cfg,
                cfg.runner.cpus_per_task,
                None if base is None else base(),
            )


def trained_files(cache: Cache, keys: Sequence[str]) -> list[dict[str, bytes]]:
    """The files of each trained group of ``keys``, as bytes: what a task reads them from (the
    driver parsed every environment's tensors itself, ~8 ms each of its serial work, and
    imported torch to)."""
    from pcpg_dist.stages.bc import TrainedCells

    return [
        {n: (cache.path("train", k) / n).read_bytes() for n in TrainedCells.FILES} for k in keys
    ]


# --------------------------------------------------------------------------- evaluation
def _evaluate(batch: Batch, stage: Stage) -> None:
    """One evaluation per environment (MLflow child runs are the hooks', after the summary)."""
    jobs: dict[str, tuple] = {}
    for p in batch.points:
        for e in p.units:
            tkeys = p.train_keys(e)
            p.ekeys[e] = k = declared.evaluate_key(tkeys, p.cfg)
            if k not in jobs and batch.cache.done("evaluate", k) is None:
                trained = trained_files(batch.cache, tkeys)
                labels, margins = clusters_of(batch.clusters[p.ckeys[e]])
                model = batch.cache.path("cluster", p.ckeys[e]) / "model"
                jobs[k] = (
                    p.refs[e],
                    labels,
                    trained,
                    p.cfg,
                    p.cfg.runner.cpus_per_task,
                    margins,
                    files_of(model) if model.is_dir() else None,
                )

    def save(key: str, res: dict) -> None:
        batch.cache.store("evaluate", key, res["files"], {"stage": "evaluate"})

    batch.computed[stage.counter] = batch.run_jobs(stage, jobs, save)


#: how the driver runs each declared stage that has jobs (the data stage is :func:`_load_data`)
STAGE_DRIVERS: dict[str, Callable[[Batch, Stage], None]] = {
    CLUSTER.name: _cluster,
    TRAIN.name: _train,
    EVALUATE.name: _evaluate,
}
