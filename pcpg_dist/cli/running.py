"""The commands that run the pipeline: generate, run, sweep, cluster, tune (results on stdout)."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from pcpg_dist.common.commands import command


def generate(args: argparse.Namespace) -> None:
    from pcpg_dist.common.progress import out as console  # results: stdout
    from pcpg_dist.config.overrides import load_config_with
    from pcpg_dist.orchestration import ray_pool
    from pcpg_dist.pipeline.checks import check_apart_from_inputs
    from pcpg_dist.stages.data import generate_to

    cfg = load_config_with(args.config, args.overrides)
    check_apart_from_inputs(cfg, Path(args.out), "--out")
    _start_ray(args)
    datasets = generate_to(cfg, Path(args.out), not args.quiet, ray_pool.fan_out)
    for env, ds in datasets.items():
        console.print(
            f"{env}: {ds.n_trajectories} trajectories, {ds.n_rows} rows, "
            f"success {ds.success.mean():.3f}, mean length {ds.lengths.mean():.1f}"
        )
    console.print(f"wrote {args.out}/manifest.json")


def _start_ray(args: argparse.Namespace) -> None:
    """Ray in this process or joined; on a local Ray, the numba kernels compile in the
    background meanwhile where a fresh install has not cached them yet."""
    import os

    from pcpg_dist.cli.warm_kernels import start_in_background
    from pcpg_dist.orchestration.ray_pool import init_ray

    if args.ray_address is None and not os.environ.get("RAY_ADDRESS"):
        start_in_background()
    init_ray(args.ray_address)


def _check_tracking(args: argparse.Namespace) -> None:
    """Fail in seconds on a dead MLflow server, before Ray and torch start."""
    if not args.no_tracking:
        from pcpg_dist.tracking.connection import check_tracking_uri
        from pcpg_dist.tracking.store import default_tracking_uri

        check_tracking_uri(args.tracking_uri or default_tracking_uri())


def run(args: argparse.Namespace) -> None:
    from pcpg_dist.api.run import run_experiment
    from pcpg_dist.common.progress import out
    from pcpg_dist.config.overrides import load_config_with
    from pcpg_dist.reporting.summary import print_summary

    cfg = load_config_with(args.config, args.overrides)
    _check_tracking(args)
    _start_ray(args)
    result = run_experiment(
        cfg,
        workdir=Path(args.workdir),
        tracking_uri=args.tracking_uri,
        track=not args.no_tracking,
        show_progress=not args.quiet,
        command=" ".join(["pcpg", *sys.argv[1:]]),
    )
    # results on stdout; plain print below: commands stay one copyable line
    print_summary(result, out, method=result.method or cfg.clustering.method, bc=cfg.bc)
    if result.parent_run_id:
        _print_links(args, "MLflow parent run", result.parent_run_id)
    print(f"outputs: {result.out_dir}/summary")
    if getattr(result, "report", None):
        print(f"report: {result.report}")


def _print_links(args: argparse.Namespace, what: str, run_id: str) -> None:
    """The MLflow run, how to open the UI on a local store, and the runs table's address: plain
    prints, so each command stays one copyable line."""
    from pcpg_dist.tracking.logged import ui_link
    from pcpg_dist.tracking.store import default_tracking_uri

    uri = args.tracking_uri or default_tracking_uri()
    print(f"{what}: {run_id}")
    if not uri.startswith(("http://", "https://")):
        print(f"start the UI: {command('mlflow', 'ui', '--backend-store-uri', uri)}")
    print(f"runs table: {ui_link(uri, run_id)}")


def sweep(args: argparse.Namespace) -> None:
    """A grid over config axes, every point together on Ray; shared stages run once."""
    from pcpg_dist.api.sweep import run_sweep
    from pcpg_dist.config.overrides import split_sweep_items

    axes, fixed = split_sweep_items(args.axes)
    _check_tracking(args)
    _start_ray(args)
    res = run_sweep(
        args.config,
        axes,
        fixed,
        workdir=Path(args.workdir),
        tracking_uri=args.tracking_uri,
        track=not args.no_tracking,
        show_progress=not args.quiet,
        command=" ".join(["pcpg", *sys.argv[1:]]),
    )
    _print_points(res)
    print(
        f"sweep: {len(res.rows)} points ({res.ran} run now, {len(res.rows) - res.ran} finished before) "
        f"in {res.seconds:.1f} s"
    )
    print(f"table: {res.out_dir / 'summary.csv'}")
    print(f"report: {res.out_dir / 'report.html'}  ({len(res.figures)} figures)")
    if res.parent_run_id:
        _print_links(args, "MLflow sweep run", res.parent_run_id)


def _print_points(res) -> None:
    """The sweep's points on stdout: axis values, then PCPG and No Clustering at p = 1 and at the
    smallest p, the clustering accuracy and its label-free stability (every column: summary.csv
    and the report)."""
    from rich.table import Table

    from pcpg_dist.common.progress import out as console
    from pcpg_dist.reporting.sweep_files import ps_of

    keys = {k for r in res.rows for k in r}
    ps = ps_of(keys)
    shown = [("clustering/accuracy", "clust. acc"), ("clustering/stability", "stab.")]
    for p in dict.fromkeys(ps[:1] + ps[-1:]):
        shown += [(f"pcpg/accuracy/p{p}", f"PCPG p{p}"), (f"baseline/accuracy/p{p}", f"NC p{p}")]
    shown = [(k, title) for k, title in shown if k in keys]
    table = Table(title="Sweep points (mean over seeds; NC = No Clustering)", title_justify="left")
    for axis in res.axes:
        table.add_column(
            axis.rsplit(".", 1)[-1]
            if sum(a.rsplit(".", 1)[-1] == axis.rsplit(".", 1)[-1] for a in res.axes) == 1
            else axis
        )
    for _, title in shown:
        table.add_column(title, justify="right")
    for row in res.rows:
        values = [row.get(k) for k, _ in shown]
        table.add_row(
            *(str(row.get(a, "")) for a in res.axes),
            *("-" if v is None or v == "" else f"{float(v):.3f}" for v in values),
        )
    console.print(table)


def cluster(args: argparse.Namespace) -> None:
    """Step A alone: one clustering per environment on Ray; saves models + labels."""
    from pcpg_dist.api.cluster import cluster
    from pcpg_dist.common.files import confined
    from pcpg_dist.common.progress import out as console  # results: stdout
    from pcpg_dist.config.overrides import load_config_with
    from pcpg_dist.stages.clustering.confidence import verdict_of
    from pcpg_dist.stages.clustering.style_weights import apart_line

    cfg = load_config_with(args.config, args.overrides)
    _start_ray(args)
    out = Path(args.out)
    results = cluster(cfg, out, Path(args.data) if args.data else None, not args.quiet)
    for env, res in results.items():
        shown = ", ".join(
            f"{k.split('/')[1]} {v:.3f}"
            for k, v in res["metrics"].items()
            if k.split("/")[1]
            in ("ari", "nmi", "accuracy", "silhouette", "stability", "fit_seconds")
        )
        console.print(f"{env}: {shown}  model: {confined(out, env, 'unit name') / 'model'}")
        said = verdict_of(res["metrics"], cfg.clustering.k)
        if said.verdict != "not measured":
            console.print(f"{env}: confidence without labels: {said.line()}")
        if res.get("style_weights"):  # a clustering by the moves' features: what each weighs
            import io

            import pandas as pd

            table = pd.read_csv(io.StringIO(res["style_weights"]))
            console.print(apart_line(env, table), markup=False, highlight=False)


def tune(args: argparse.Namespace) -> None:
    """Optuna study over k and the network sizes; writes the best parameters as a config."""
    from pcpg_dist.api.tune import tune
    from pcpg_dist.common.progress import out as console  # results: stdout
    from pcpg_dist.config.overrides import load_config_with
    from pcpg_dist.orchestration.tuning import open_storage, tune_settings

    cfg = load_config_with(args.config, args.overrides)
    storage = open_storage(
        args.optuna_storage, tune_settings(cfg, args.n_trials)
    )  # before Ray starts
    _check_tracking(args)
    _start_ray(args)
    res = tune(
        cfg,
        storage_url=storage,
        workdir=Path(args.workdir),
        tracking_uri=args.tracking_uri,
        track=not args.no_tracking,
        show_progress=not args.quiet,
        n_trials=args.n_trials,
        study_name=args.study_name,
        out=Path(args.out) if args.out else None,
    )
    shown = ", ".join(f"{k}={v}" for k, v in res.best_params.items())
    console.print(
        f"study {res.study_name}: trials: {trial_counts(res.n_trials)}; best score "
        f"{res.best_value:.4f} with {shown}"
    )
    if res.failed_stale:
        console.print(
            f"failed and re-queued stale trials {res.failed_stale} (their driver had stopped)"
        )
    again = (
        "" if args.workdir == "runs" else f" --workdir {shlex.quote(args.workdir)}"
    )  # the study's data
    rerun = command("pcpg", "run", str(res.best_config))
    console.print(f"best config: {res.best_config}  (run it: {rerun}{again})")
    dashboard = command("optuna-dashboard", res.storage, "--host", "127.0.0.1")
    console.print(f"dashboard: {dashboard}")


def trial_counts(counts: dict[str, int]) -> str:
    """``{'PRUNED': 2, 'COMPLETE': 1}`` (trials per Optuna state) as ``1 complete, 2 pruned``."""
    order = ["COMPLETE", "PRUNED", "FAIL", "RUNNING", "WAITING"]
    states = sorted(counts, key=lambda s: (order.index(s) if s in order else len(order), s))
    return (
        ", ".join(
            f"{counts[s]} {'failed' if s == 'FAIL' else s.lower()}" for s in states if counts[s]
        )
        or "none"
    )
