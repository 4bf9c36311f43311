"""`pcpg run` and `pcpg sweep`: generate → cluster → rank/threshold → train → evaluate → log on Ray.

Every unit of work has a content key (its config slice + its inputs' keys) and a cache folder
(:mod:`pcpg_dist.orchestration.cache`); a finished unit is never recomputed, so rerunning the same command after
Ctrl-C or a killed process continues where it stopped and ends with the same numbers.

Units: the data (the domain may fan it out on Ray), one clustering per environment, BC training in
groups of ``runner.group_size`` cells (never one task per tiny model), one evaluation per
environment. Several configs (the points of a sweep) run together stage by stage: their tasks
interleave on the cluster and a unit that two points share by key (same data, same clustering,
same trained cells) runs once.

No shared disk is assumed: tasks take their inputs as arguments and return their results as
values (arrays, metrics, files as bytes); the driver is the only process that writes the cache,
the outputs and the tracking store. MLflow comes last, from the driver, once every local result is
written, so a tracking server that goes down costs no work.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pcpg_dist.common.devices import set_threads
from pcpg_dist.common.progress import progress_bar
from pcpg_dist.common.run_folders import check_unit_name
from pcpg_dist.config import ExperimentConfig
from pcpg_dist.dataset import Dataset, atomic_write_bytes, confined, content_digest, load_datasets
from pcpg_dist.domains import contract
from pcpg_dist.domains.base import Unit
from pcpg_dist.orchestration.cache import Cache, content_key, files_of
from pcpg_dist.orchestration.ray_pool import run_tasks
from pcpg_dist.stages.ranking import check_margins_come

CODE_VERSION = (
    "2"  # bump when a stage's numbers or files change for the same config (2: bool valid masks)
)
CLUSTER_VERSION = "2"  # bump when only Step A's files change (2: result.json holds the margins)
EVAL_VERSION = "3"  # bump when only the evaluation's metrics or tables change (3: cluster_style, kept length in steps)
STAGES = ("generate", "cluster", "train", "evaluate")
# fields of a config that cannot change its evaluation units (dataset, split, what Step A sees)
NOT_IN_UNITS = {"name", "clustering", "bc", "evaluation", "runner", "tuning", "seeds", "sweep"}


@dataclass
class RunResult:
    """What `pcpg run` produced: where, the summary metrics, and where time went."""

    out_dir: Path
    metrics: dict[str, float]
    clustering: dict[str, dict[str, float]]
    stage_seconds: dict[str, float] = field(default_factory=dict)
    parent_run_id: str | None = None
    computed: dict[str, int] = field(default_factory=dict)
    report: Path | None = None
    cached_stages: list[str] = field(default_factory=list)


@dataclass
class Point:
    """One config to run: where its outputs go and (in a sweep) what it overrides."""

    cfg: ExperimentConfig
    out: Path
    params: dict[str, str] = field(default_factory=dict)
    command: str = ""
    # filled while running
    units: dict[str, Unit] = field(default_factory=dict)
    refs: dict[str, Any] = field(default_factory=dict)
    digests: dict[str, str] = field(
        default_factory=dict
    )  # what each unit's clusterer reads, hashed
    dkey: str = ""
    ikey: str = ""  # the inputs' key, recorded in run.json (data_keys)
    ckeys: dict[str, str] = field(default_factory=dict)
    groups: list[tuple[str, str, list]] = field(default_factory=list)  # (env, train key, cells)
    ekeys: dict[str, str] = field(default_factory=dict)
    gpus: tuple[float, float] = (0.0, 0.0)  # what a (clustering, BC) task asks Ray for
    tracker: Any = None


# --------------------------------------------------------------------------- data
def data_keys(cfg: ExperimentConfig) -> tuple[str, str]:
    """``(data key, input key)`` from one reading of what the domain says identifies its data
    (settings, file contents, seed; a log is hashed once). The data key, with pcpg's code
    version, names the data in the cache; the input key, without it, is what ``run.json``
    records for ``pcpg reproduce`` to tell "the inputs changed" apart from "the code changed"."""
    parts = contract.data_key(cfg)
    return content_key(CODE_VERSION, *parts), content_key(*parts)


def data_key(cfg: ExperimentConfig) -> str:
    """Content key of the data (see :func:`data_keys`)."""
    return data_keys(cfg)[0]


def input_key(cfg: ExperimentConfig) -> str:
    """Key of the data stage's inputs (see :func:`data_keys`)."""
    return data_keys(cfg)[1]


def load_or_generate(
    cfg: ExperimentConfig, cache: Cache, show_progress: bool, key: str | None = None
) -> tuple[dict[str, Dataset], str]:
    """The config's datasets, generated once and cached under ``key`` (its :func:`data_key`)."""
    from pcpg_dist.stages.data import write_to

    key = key or data_key(cfg)
    path = cache.path("data", key)
    if cache.done("data", key) is None:
        # generated and validated in memory first: bad input leaves nothing behind
        datasets = contract.generate(cfg, show_progress)
        cache.start("data", key)
        write_to(cfg, datasets, path)
        cache.finish("data", key, {"stage": "data"})
    return load_datasets(path), key


def load_units(cfg: ExperimentConfig, cache: Cache, show_progress: bool) -> tuple[list[Unit], str]:
    """The config's evaluation units (data generated or loaded once, then cached) and the data key."""
    files, key = load_or_generate(cfg, cache, show_progress)
    units = contract.units(cfg, files)
    warn_partial_styles(units)
    return units, key


def warn_partial_styles(units: list[Unit]) -> None:
    """One warning line per unit whose styles are known for some trajectories only."""
    from pcpg_dist.pipeline import partial_styles_note

    for unit in units:
        if note := partial_styles_note(unit):
            logging.getLogger(__name__).warning("%s", note)


# --------------------------------------------------------------------------- Ray tasks
def cluster_task(unit: Unit, cluster_cfg, seed: int, threads: int) -> dict:
    """One unit's clustering (a Ray task): labels, metrics and the fitted model's files as bytes."""
    from pcpg_dist.pipeline import cluster_unit

    set_threads(threads)
    result = cluster_unit(unit, cluster_cfg, seed)
    model: dict[str, bytes] = {}
    if result.model is not None:
        with tempfile.TemporaryDirectory() as tmp:
            result.model.save(Path(tmp))
            model = files_of(tmp)
    margins = None if result.margins is None else result.margins.tolist()
    return {
        "labels": result.labels.tolist(),
        "margins": margins,
        "metrics": result.metrics,
        "model": model,
    }


def train_task(cells: list, bc_cfg, threads: int, init: list | None = None):
    """Train one group of cells in one vectorised pass (a Ray task); returns the trained arrays.
    ``init``: the cells' starting parameters (``bc.init: no_clustering``)."""
    from pcpg_dist.stages.bc import train_cells

    set_threads(threads)
    return train_cells(cells, bc_cfg, init)


def evaluate_task(
    unit: Unit,
    labels: np.ndarray,
    trained,
    cfg: ExperimentConfig,
    threads: int,
    margins: np.ndarray | None = None,
) -> dict:
    """Evaluate one unit (a Ray task): its metrics and its tables and figures as bytes."""
    from pcpg_dist.pipeline import evaluate_unit

    set_threads(threads)
    with tempfile.TemporaryDirectory() as tmp:
        metrics = evaluate_unit(unit, labels, trained, cfg, tmp, margins=margins)
        files = files_of(tmp)
    files["metrics.json"] = json.dumps(metrics, indent=1, sort_keys=True).encode()
    return {"metrics": metrics, "files": files}


# --------------------------------------------------------------------------- helpers
def _in_flight(num_cpus: int, arg_bytes: float) -> int:
    """How many tasks to submit at once: enough to keep every CPU busy, few enough that their
    queued arguments fit in half the object store."""
    import ray

    res = ray.cluster_resources()
    slots = max(1, int(res.get("CPU", 1) // max(num_cpus, 1)))
    store = res.get("object_store_memory", 2e8)
    return max(slots, min(4 * slots, int(0.5 * store / max(arg_bytes, 1.0))))


def _nbytes(x: Any, depth: int = 0) -> int:
    """Rough size of a task argument: its NumPy arrays (a few levels into lists and objects)."""
    if isinstance(x, np.ndarray):
        return x.nbytes
    if depth > 4:
        return 64
    if isinstance(x, list | tuple):
        return sum(_nbytes(v, depth + 1) for v in x)
    if isinstance(x, dict):
        return sum(_nbytes(v, depth + 1) for v in x.values())
    if hasattr(x, "__dict__"):
        return sum(_nbytes(v, depth + 1) for v in vars(x).values())
    return 64


def _collect_agents(target: Path, models: dict[str, list[Path]]) -> Path:
    """``target/<env>/<group>.pt|.json`` (a new folder): every trained cell of the run, for the pyfunc
    model, and ``target/index.json``, the hash of each file per environment."""
    from pcpg_dist.common.run_folders import write_agents_index

    for env, paths in models.items():
        (target / env).mkdir(parents=True)
        for i, p in enumerate(paths):
            for suffix in (".pt", ".json"):
                shutil.copyfile(p.with_suffix(suffix), target / env / f"group{i:03d}{suffix}")
    write_agents_index(target)
    return target


def _run_stage(
    description: str,
    fn: Callable,
    jobs: dict[str, tuple],
    num_cpus: int,
    save: Callable[[str, Any], None],
    show_progress: bool,
    gpus: dict[str, float] | None = None,
) -> int:
    """Run one task per key of ``jobs`` (keys shared by several points run once); ``save`` each.
    ``gpus``: what each key's task asks for (none where missing)."""
    keys = list(jobs)
    calls = [jobs[k] for k in keys]
    limit = _in_flight(num_cpus, max((_nbytes(c) for c in calls), default=0)) if calls else 1
    run_tasks(
        fn,
        calls,
        description,
        num_cpus=num_cpus,
        on_result=lambda i, res: save(keys[i], res),
        show_progress=show_progress and bool(calls),
        max_in_flight=limit,
        num_gpus=[(gpus or {}).get(k, 0.0) for k in keys],
    )
    return len(calls)


def cluster_gpus(cfg: ExperimentConfig, node_gpus: float) -> float:
    """GPUs a clustering task of ``cfg`` asks Ray for (none unless a neural method is on a GPU);
    ``node_gpus``: the most one live node has (:func:`pcpg_dist.orchestration.ray_pool.node_gpus`)."""
    from pcpg_dist.common.devices import stage_gpus
    from pcpg_dist.config.stages import NEURAL_CLUSTERERS

    if cfg.clustering.device == "cpu" or cfg.clustering.method not in NEURAL_CLUSTERERS:
        return 0.0
    return stage_gpus(
        cfg.clustering.device, cfg.runner.gpus_per_task, node_gpus, "clustering.device"
    )


def trains_a_network(cluster_cfg, dataset) -> bool:
    """Whether Step A trains a network on ``dataset`` (a unit's clustering input): ``bag_auto``
    does only on continuous states (its fallback), so on discrete ones its task needs no GPU."""
    from pcpg_dist.config.stages import NEURAL_CLUSTERERS

    if cluster_cfg.method != "bag_auto":
        return cluster_cfg.method in NEURAL_CLUSTERERS
    from pcpg_dist.stages.clustering.cluster import falls_back_to_lstm

    return falls_back_to_lstm(dataset)


def unit_cluster_gpus(share: float, cluster_cfg, dataset) -> float:
    """What one unit's clustering task asks for: the stage's ``share`` where it trains a network."""
    return share if share and trains_a_network(cluster_cfg, dataset) else 0.0


def bc_gpus(cfg: ExperimentConfig, node_gpus: float) -> float:
    """GPUs a BC training task of ``cfg`` asks Ray for (``node_gpus`` as in :func:`cluster_gpus`)."""
    from pcpg_dist.common.devices import stage_gpus
    from pcpg_dist.stages.bc import runs_on_cpu_only

    if cfg.bc.device == "cpu" or (cfg.bc.device == "auto" and runs_on_cpu_only(cfg.bc)):
        return 0.0
    return stage_gpus(cfg.bc.device, cfg.runner.gpus_per_task, node_gpus, "bc.device")


# --------------------------------------------------------------------------- the run
def run_experiment(
    cfg: ExperimentConfig,
    workdir: Path = Path("runs"),
    tracking_uri: str | None = None,
    track: bool = True,
    show_progress: bool = True,
    command: str = "",
) -> RunResult:
    """Run (or resume) a whole experiment; Ray must be initialised by the caller."""
    out = Path(workdir).resolve() / cfg.name
    return run_points(
        [Point(cfg, out, command=command)],
        out / "cache",
        tracking_uri=tracking_uri,
        track=track,
        show_progress=show_progress,
    )[0]


def run_points(
    points: list[Point],
    cache_root: Path,
    tracking_uri: str | None = None,
    track: bool = True,
    show_progress: bool = True,
    sweep_parent_id: str | None = None,
) -> list[RunResult]:
    """Run (or resume) several configs together, stage by stage, sharing units by content key.

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
    try:
        return _run_points(
            points, Cache(cache_root), tracking_uri, track, show_progress, sweep_parent_id
        )
    except BaseException:  # bad input, an OSError, Ctrl-C: whatever it was, leave no empty folders
        if created and not cache_root.exists():  # failed before anything was cached
            Path(lock.lock_file).unlink(missing_ok=True)
            for d in created:
                with contextlib.suppress(OSError):
                    d.rmdir()
        raise
    finally:
        lock.release()


def _run_points(
    points: list[Point],
    cache: Cache,
    tracking_uri: str | None,
    track: bool,
    show_progress: bool,
    sweep_parent_id: str | None,
) -> list[RunResult]:
    import ray

    from pcpg_dist.orchestration.ray_pool import check_resources, node_gpus
    from pcpg_dist.pipeline import plan_unit
    from pcpg_dist.stages.bc import TrainedCells, finetune_config, split_for_init

    times: dict[str, float] = {}
    computed = {"data": 0, "clustering": 0, "train_groups": 0, "evaluations": 0}
    most_gpus = node_gpus()
    for p in points:
        check_resources(p.cfg.runner.cpus_per_task)
        # a GPU setting no node can serve fails here
        p.gpus = (cluster_gpus(p.cfg, most_gpus), bc_gpus(p.cfg, most_gpus))

    # ---- data: each distinct dataset loaded or generated once, each distinct unit put in Ray once.
    # A bad input file fails here, before any MLflow run or cache entry exists.
    t0 = time.perf_counter()
    datas: dict[str, dict[str, Dataset]] = {}
    unit_sets: dict[str, tuple[dict[str, Unit], dict[str, Any], dict[str, str]]] = {}
    for p in points:
        p.dkey, p.ikey = data_keys(p.cfg)
        if p.dkey not in datas:
            computed["data"] += cache.done("data", p.dkey) is None
            datas[p.dkey] = load_or_generate(p.cfg, cache, show_progress, p.dkey)[0]
        ukey = content_key(p.dkey, p.cfg.model_dump(mode="json", exclude=NOT_IN_UNITS))
        if ukey not in unit_sets:
            units = {u.name: u for u in contract.units(p.cfg, datas[p.dkey])}
            warn_partial_styles(list(units.values()))
            for name in units:
                confined(p.out, name, "unit name")  # unit names become folder and run names
                check_unit_name(name)
            check_margins_come(p.cfg, [u.clustered for u in units.values()])
            unit_sets[ukey] = (
                units,
                {n: ray.put(u) for n, u in units.items()},
                {n: content_digest(u.clustered) for n, u in units.items()},
            )
        p.units, p.refs, p.digests = unit_sets[ukey]
    times["generate"] = time.perf_counter() - t0
    # one task holds a unit, its copies in the stage's arrays, and a torch runtime (~600 MB)
    largest = max((_nbytes(u.dataset) for p in points for u in p.units.values()), default=0)
    check_resources(max(p.cfg.runner.cpus_per_task for p in points), 6e8 + 8.0 * largest)

    if track:
        from pcpg_dist.tracking import Tracker

        for p in points:
            extra = (
                {"parent_run_id": sweep_parent_id, "params": p.params} if sweep_parent_id else {}
            )
            p.tracker = Tracker.start(p.cfg, tracking_uri, p.out, **extra)
    try:
        threads = max(p.cfg.runner.cpus_per_task for p in points)

        # ---- Step A: one clustering per (data, environment, clustering settings)
        t0 = time.perf_counter()
        jobs: dict[str, tuple] = {}
        gpus: dict[str, float] = {}
        for p in points:
            for e, u in p.units.items():
                # the input's digest, not only the settings: a domain may derive it from any of
                # them (Mario's valid mask comes from the training episodes, so from the split)
                p.ckeys[e] = k = content_key(
                    CODE_VERSION,
                    CLUSTER_VERSION,
                    p.dkey,
                    e,
                    p.cfg.clustering,
                    p.cfg.seed,
                    u.cluster_input_note,
                    p.digests[e],
                )
                if k not in jobs and cache.done("cluster", k) is None:
                    jobs[k] = (p.refs[e], p.cfg.clustering, p.cfg.seed, p.cfg.runner.cpus_per_task)
                    gpus[k] = unit_cluster_gpus(p.gpus[0], p.cfg.clustering, u.clustered)

        def save_cluster(key: str, res: dict) -> None:
            files = {
                "result.json": json.dumps(
                    {k: res[k] for k in ("labels", "margins", "metrics")}
                ).encode(),
                **{f"model/{n}": b for n, b in res["model"].items()},
            }
            cache.store("cluster", key, files, {"stage": "cluster"})

        computed["clustering"] = _run_stage(
            "Step A: clustering", cluster_task, jobs, threads, save_cluster, show_progress, gpus
        )
        clusters = {
            k: cache.read_json("cluster", k, "result.json")
            for p in points
            for k in p.ckeys.values()
        }
        times["cluster"] = time.perf_counter() - t0

        # ---- Steps B + C: plan every cell, train in groups. With bc.init no_clustering a second
        # round trains the other cells, each from the first round's No Clustering agent.
        t0 = time.perf_counter()
        later: list[tuple[Point, str, list, list[str]]] = []
        jobs = {}
        # ranking and cutting a unit into cells runs here, in the driver: on 40,000 trajectories
        # that is ~15 s, which showed as a frozen Step A bar
        with progress_bar(
            "Step B: ranking", total=sum(len(p.units) for p in points), enabled=show_progress
        ) as advance:
            for p in points:
                cfg = p.cfg
                for e, u in p.units.items():
                    labels, margins = _clusters_of(clusters[p.ckeys[e]])
                    first, rest = split_for_init(plan_unit(u, labels, cfg, margins=margins), cfg.bc)
                    _add_groups(p, e, first, cache, jobs, cfg.bc, [])
                    if rest:
                        later.append((p, e, rest, [k for ge, k, _ in p.groups if ge == e]))
                    advance()

        def save_group(key: str, trained) -> None:
            folder = cache.start("train", key)
            trained.save(folder / "cells")
            cache.finish("train", key, {"stage": "train", "cells": len(trained.specs)})

        def train_gpus() -> dict[str, float]:
            return {k: p.gpus[1] for p in points for _, k, _ in p.groups}

        computed["train_groups"] = _run_stage(
            "Step C: BC groups", train_task, jobs, threads, save_group, show_progress, train_gpus()
        )
        if later:
            jobs = {}
            for p, e, rest, base_keys in later:
                # read only when some group of this unit is not cached yet
                base = functools.cache(
                    lambda keys=tuple(base_keys): TrainedCells.concat(
                        [TrainedCells.load(cache.path("train", k) / "cells") for k in keys]
                    )
                )
                _add_groups(p, e, rest, cache, jobs, finetune_config(p.cfg.bc), base_keys, base)
            computed["train_groups"] += _run_stage(
                "Step C: BC groups from No Clustering",
                train_task,
                jobs,
                threads,
                save_group,
                show_progress,
                train_gpus(),
            )
        times["train"] = time.perf_counter() - t0

        # ---- Evaluation per environment (MLflow child runs are logged after the summary)
        t0 = time.perf_counter()
        jobs = {}
        for p in points:
            for e in p.units:
                tkeys = [k for ge, k, _ in p.groups if ge == e]
                p.ekeys[e] = k = content_key(
                    CODE_VERSION, EVAL_VERSION, tkeys, p.cfg.evaluation, p.cfg.ranking
                )
                if k not in jobs and cache.done("evaluate", k) is None:
                    trained = TrainedCells.concat(
                        [TrainedCells.load(cache.path("train", t) / "cells") for t in tkeys]
                    )
                    labels, margins = _clusters_of(clusters[p.ckeys[e]])
                    jobs[k] = (
                        p.refs[e],
                        labels,
                        trained,
                        p.cfg,
                        p.cfg.runner.cpus_per_task,
                        margins,
                    )

        def save_eval(key: str, res: dict) -> None:
            cache.store("evaluate", key, res["files"], {"stage": "evaluate"})

        computed["evaluations"] = _run_stage(
            "Evaluation", evaluate_task, jobs, threads, save_eval, show_progress
        )
        times["evaluate"] = time.perf_counter() - t0

        # every local result first (summary, agents, report), so all of it is kept when the
        # tracking server is down; then the MLflow runs, one bar for every point's environments
        results = [
            _finish_point(p, cache, clusters, dict(times), computed, len(points)) for p in points
        ]
        unlogged = {
            id(p): [e for e in p.units if not p.tracker.env_logged(e, p.ekeys[e])]
            if p.tracker is not None
            else []
            for p in points
        }
        total = sum(len(v) for v in unlogged.values())
        with progress_bar(
            "MLflow child runs", total=total, enabled=show_progress and bool(total)
        ) as advance:
            for p, result in zip(points, results, strict=True):
                _log_point(p, cache, clusters, result, unlogged[id(p)], advance)
        return results
    except BaseException:
        for p in points:
            if p.tracker is not None:
                p.tracker.fail()
        raise


def _clusters_of(result: dict) -> tuple[np.ndarray, np.ndarray | None]:
    """A cached clustering's labels and margins (None from a clusterer without a likelihood)."""
    margins = result.get("margins")
    return (
        np.asarray(result["labels"], np.int64),
        None if margins is None else np.asarray(margins, np.float64),
    )


def _add_groups(
    p: Point,
    unit: str,
    cells: list,
    cache: Cache,
    jobs: dict[str, tuple],
    bc_cfg,
    base_keys: list[str],
    base: Callable[[], Any] | None = None,
) -> None:
    """Cut ``cells`` into groups of ``runner.group_size``: each a content-keyed training job
    (unless cached); with ``base`` (returns the No Clustering agents) each cell starts from its own."""
    from pcpg_dist.stages.bc import init_from

    cfg = p.cfg
    for g in range(0, len(cells), cfg.runner.group_size):
        chunk = cells[g : g + cfg.runner.group_size]
        key = content_key(
            CODE_VERSION,
            p.ckeys[unit],
            cfg.ranking,
            cfg.bc,
            cfg.evaluation.corruption_levels,
            cfg.evaluation.corruption_ps,
            [c.key for c in chunk],
            base_keys,
        )
        p.groups.append((unit, key, chunk))
        if key not in jobs and cache.done("train", key) is None:
            jobs[key] = (
                chunk,
                bc_cfg,
                cfg.runner.cpus_per_task,
                None if base is None else init_from(chunk, base()),
            )


STAGING = ".finishing"  # RUN/.finishing: the next summary, agents and report while they are written


def _swap_in(out: Path, staging: Path, names: tuple[str, ...]) -> None:
    """Replace ``out/<name>`` by ``staging/<name>`` for each name, by renames. The old summary is
    moved aside first, so between the renames there is no summary rather than a mixed one."""
    old = staging / "old"
    old.mkdir(exist_ok=True)
    if "summary" in names and (out / "summary").exists():
        (out / "summary").rename(old / "summary")
    for name in names:
        if (out / name).exists():
            (out / name).rename(old / name)
        (staging / name).rename(out / name)


def _finish_point(
    p: Point,
    cache: Cache,
    clusters: dict,
    times: dict[str, float],
    computed: dict[str, int],
    batch: int = 1,
) -> RunResult:
    """Across one point's environments: summary tables, figures, agents and report (local only).
    ``batch``: the points whose stages ran together (a sweep's); their times and counts are shared."""
    from pcpg_dist.common.provenance import provenance
    from pcpg_dist.reporting.report import render
    from pcpg_dist.reporting.summary import write_summary

    t0 = time.perf_counter()
    cfg, out, envs = p.cfg, p.out, list(p.units)
    # Summary, agents and report are built in `staging` and swapped in by renames, the summary
    # (run.json inside) last: a killed write leaves the old complete summary or none, never a mix.
    staging = out / STAGING
    if staging.exists():  # left by a run killed while finishing
        shutil.rmtree(staging)
    staging.mkdir(parents=True)
    per_env = {e: cache.read_json("evaluate", p.ekeys[e], "metrics.json") for e in envs}
    cluster_metrics = {e: clusters[p.ckeys[e]]["metrics"] for e in envs}
    eval_dirs = {e: cache.path("evaluate", p.ekeys[e]) for e in envs}
    metrics = write_summary(cfg, staging / "summary", eval_dirs, per_env, cluster_metrics)
    models = {
        e: [cache.path("train", k) / "cells" for ge, k, _ in p.groups if ge == e] for e in envs
    }
    _collect_agents(staging / "agents", models)
    times["summary"] = time.perf_counter() - t0

    # A stage served wholly from the cache keeps the timing of the run that computed it.
    stage_done = {
        "generate": computed["data"],
        "cluster": computed["clustering"],
        "train": computed["train_groups"],
        "evaluate": computed["evaluations"],
    }
    cached = [s for s in STAGES if not stage_done[s]]
    try:
        before = json.loads((out / "summary" / "run.json").read_text()).get("stage_seconds", {})
    except (OSError, ValueError, AttributeError):
        before = {}
    for s in cached:
        if isinstance(before.get(s), int | float):
            times[s] = before[s]
    result = RunResult(
        out_dir=out,
        metrics=metrics,
        clustering=cluster_metrics,
        stage_seconds=times,
        computed=computed,
        cached_stages=cached,
        parent_run_id=p.tracker.parent_id if p.tracker else None,
    )
    run_info = {
        "config": cfg.model_dump(mode="json"),
        "config_hash": cfg.hash(),
        "command": p.command or f"pcpg run <config of {cfg.name}>",
        "overrides": p.params,
        "provenance": provenance(),
        "stage_seconds": times,
        "cached_stages": cached,
        "parent_run_id": result.parent_run_id,
        "computed": computed,
        "code_version": CODE_VERSION,
        "input_key": p.ikey,
        "batch_points": batch,
    }
    atomic_write_bytes(
        staging / "summary" / "run.json", json.dumps(run_info, indent=1, default=str).encode()
    )
    _swap_in(out, staging, ("agents", "summary"))
    render(out / "summary", staging / "report")
    _swap_in(out, staging, ("report",))
    shutil.rmtree(staging)
    result.report = out / "report" / "report.html"
    return result


def _log_point(
    p: Point,
    cache: Cache,
    clusters: dict,
    result: RunResult,
    unlogged: list[str],
    advance: Callable[..., None],
) -> None:
    """One point's MLflow runs, after every local result is written: child runs for the
    ``unlogged`` environments (``advance()`` after each), then the parent. A rerun logs only the
    environments without a FINISHED child run, recomputing nothing."""
    if p.tracker is None:
        return
    from pcpg_dist.tracking import log_environment

    t0 = time.perf_counter()
    for e in unlogged:
        models = [cache.path("train", k) / "cells" for ge, k, _ in p.groups if ge == e]
        log_environment(
            p.tracker.child_info(e, p.ekeys[e], clusters[p.ckeys[e]]["metrics"]),
            e,
            str(cache.path("evaluate", p.ekeys[e])),
            cache.read_json("evaluate", p.ekeys[e], "metrics.json"),
            [str(m.with_suffix(".pt")) for m in models],
        )
        advance()
    p.tracker.finish(result, agents_dir=p.out / "agents", report_dir=p.out / "report")
    result.stage_seconds["tracking"] = time.perf_counter() - t0
