"""The ``pcpg`` command line. Every user mistake prints one line and exits with code 2."""

from __future__ import annotations

import argparse
import logging
import os
import shlex
import sys
from pathlib import Path

from pcpg_dist.common.errors import PcpgError, Terminated, catch_sigterm


def _cmd_generate(args: argparse.Namespace) -> None:
    from pcpg_dist.common.progress import out as console  # results: stdout
    from pcpg_dist.config.overrides import load_config_with
    from pcpg_dist.orchestration.ray_pool import init_ray
    from pcpg_dist.stages.data import generate_to

    cfg = load_config_with(args.config, args.overrides)
    init_ray(args.ray_address)
    datasets = generate_to(cfg, Path(args.out), show_progress=not args.quiet)
    for env, ds in datasets.items():
        console.print(
            f"{env}: {ds.n_trajectories} trajectories, {ds.n_rows} rows, "
            f"success {ds.success.mean():.3f}, mean length {ds.lengths.mean():.1f}"
        )
    console.print(f"wrote {args.out}/manifest.json")


def _check_tracking(args: argparse.Namespace) -> None:
    """Fail in seconds on a dead MLflow server, before Ray and torch start."""
    if not args.no_tracking:
        from pcpg_dist.tracking.connection import check_tracking_uri
        from pcpg_dist.tracking.store import default_tracking_uri

        check_tracking_uri(args.tracking_uri or default_tracking_uri())


def _cmd_run(args: argparse.Namespace) -> None:
    from pcpg_dist.api.run import run_experiment
    from pcpg_dist.common.progress import out
    from pcpg_dist.config.overrides import load_config_with
    from pcpg_dist.orchestration.ray_pool import init_ray
    from pcpg_dist.reporting.summary import print_summary

    cfg = load_config_with(args.config, args.overrides)
    _check_tracking(args)
    init_ray(args.ray_address)
    result = run_experiment(
        cfg,
        workdir=Path(args.workdir),
        tracking_uri=args.tracking_uri,
        track=not args.no_tracking,
        show_progress=not args.quiet,
        command=" ".join(["pcpg", *sys.argv[1:]]),
    )
    print_summary(
        result, out
    )  # results on stdout; plain print below: commands stay one copyable line
    if result.parent_run_id:
        from pcpg_dist.tracking.logged import ui_link
        from pcpg_dist.tracking.store import default_tracking_uri

        uri = args.tracking_uri or default_tracking_uri()
        print(f"MLflow parent run: {result.parent_run_id}")
        if not uri.startswith(("http://", "https://")):
            print(f"start the UI: uv run mlflow ui --backend-store-uri {uri}")
        print(f"runs table: {ui_link(uri, result.parent_run_id)}")
    print(f"outputs: {result.out_dir}/summary")
    if getattr(result, "report", None):
        print(f"report: {result.report}")


def _cmd_sweep(args: argparse.Namespace) -> None:
    """A grid over config axes, every point together on Ray; shared stages run once."""
    from pcpg_dist.api.sweep import run_sweep
    from pcpg_dist.config.overrides import split_sweep_items
    from pcpg_dist.orchestration.ray_pool import init_ray

    axes, fixed = split_sweep_items(args.axes)
    _check_tracking(args)
    init_ray(args.ray_address)
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
        from pcpg_dist.tracking.logged import ui_link
        from pcpg_dist.tracking.store import default_tracking_uri

        uri = args.tracking_uri or default_tracking_uri()
        print(f"MLflow sweep run: {res.parent_run_id}")
        if not uri.startswith(("http://", "https://")):
            print(f"start the UI: uv run mlflow ui --backend-store-uri {uri}")
        print(f"runs table: {ui_link(uri, res.parent_run_id)}")


def _print_points(res) -> None:
    """The sweep's points on stdout: axis values, then PCPG and No Clustering at p = 1 and at the
    smallest p, and the clustering accuracy (every column: summary.csv and the report)."""
    from rich.table import Table

    from pcpg_dist.common.progress import out as console
    from pcpg_dist.reporting.sweep_files import ps_of

    keys = {k for r in res.rows for k in r}
    ps = ps_of(keys)
    shown = [("clustering/accuracy", "clust. acc")]
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


def _cmd_report(args: argparse.Namespace) -> None:
    from pcpg_dist.api.report import resolve
    from pcpg_dist.common.progress import out as console  # results: stdout
    from pcpg_dist.reporting.report import render

    source = resolve(args.target, args.tracking_uri, Path(args.workdir))
    if source.kind == "sweep":  # a sweep's page: its points and figures (HTML only)
        from pcpg_dist.reporting.sweep_page import render_sweep_report

        out = Path(args.out) if args.out else source.folder
        html_path = render_sweep_report(source.folder, out)
        console.print(f"sweep report: {html_path}")
    else:
        out = Path(args.out) if args.out else source.folder.parent / "report"
        html_path, md_path = render(source.folder, out, reproduce_target=source.run_id)
        console.print(f"report: {html_path}\nmarkdown: {md_path}")
    if args.pdf:
        from pcpg_dist.reporting.pdf import export_pdf

        console.print(f"pdf: {export_pdf(html_path)}")


def _cmd_reproduce(args: argparse.Namespace) -> None:
    """Rerun a logged run in a fresh folder; exit 1 when some metric differs."""
    from pcpg_dist.api.reproduce import cli_reproduce

    code = cli_reproduce(args)
    if code:
        raise SystemExit(code)


def _cmd_cluster(args: argparse.Namespace) -> None:
    """Step A alone: one clustering per environment on Ray; saves models + labels."""
    from pcpg_dist.api.cluster import cluster
    from pcpg_dist.common.files import confined
    from pcpg_dist.common.progress import out as console  # results: stdout
    from pcpg_dist.config.overrides import load_config_with
    from pcpg_dist.orchestration.ray_pool import init_ray

    cfg = load_config_with(args.config, args.overrides)
    init_ray(args.ray_address)
    out = Path(args.out)
    results = cluster(cfg, out, Path(args.data) if args.data else None, not args.quiet)
    for env, res in results.items():
        shown = ", ".join(
            f"{k.split('/')[1]} {v:.3f}"
            for k, v in res["metrics"].items()
            if k.split("/")[1] in ("ari", "nmi", "accuracy", "silhouette", "fit_seconds")
        )
        console.print(f"{env}: {shown}  model: {confined(out, env, 'unit name') / 'model'}")


def _cmd_classify(args: argparse.Namespace) -> None:
    """Label trajectories of a dataset with a fitted clustering model's styles."""
    import pandas as pd

    from pcpg_dist.common.files import atomic_write_bytes
    from pcpg_dist.common.progress import out as console  # results: stdout
    from pcpg_dist.common.run_folders import check_outside_run
    from pcpg_dist.dataset import load_dataset
    from pcpg_dist.stages.clustering import clustering_metrics, load_model

    # by default into the current folder: the dataset's folder may be a signed `pcpg generate` output
    out = Path(args.out) if args.out else Path(Path(args.dataset).stem + ".styles.csv")
    check_classify_out(out, Path(args.model), Path(args.dataset))
    check_outside_run(out)
    model = load_model(Path(args.model))
    ds = load_dataset(Path(args.dataset))
    pred = model.predict(ds)
    # the logs' own ids where they were not integers (pcpg numbers those in sorted order)
    table = pd.DataFrame(
        {
            "trajectory": ds.trajectory_ids if ds.source_ids is None else ds.source_ids,
            "predicted_style": pred,
        }
    )
    atomic_write_bytes(out, table.to_csv(index=False).encode())
    console.print(
        f"{ds.n_trajectories} trajectories -> {out}; cluster sizes "
        f"{[int((pred == c).sum()) for c in range(int(pred.max()) + 1)]}"
    )
    unknown = model.unknown_rows(ds)
    if unknown is not None:
        console.print(f"{unknown:.0%} of the rows are in states the model was not fitted on")
        if unknown > 0.1:  # a fresh sample of the same layout: ~1 % (docs/clustering.md)
            logging.getLogger(__name__).warning(
                "%s: %.0f%% of the rows are in states %s was not fitted on: is it the same layout or "
                "game? Their labels rest on the remaining rows",
                args.dataset,
                100 * unknown,
                args.model,
            )
    if (ds.styles >= 0).all():
        m = clustering_metrics(ds.styles, pred)
        console.print(
            "against the true styles: "
            + ", ".join(f"{k} {v:.3f}" for k, v in m.items() if isinstance(v, float))
        )


def check_classify_out(out: Path, model: Path, dataset: Path) -> None:
    """The labels never overwrite the inputs: the dataset (or its manifest), a file of the model."""
    from pcpg_dist.common.errors import ConfigError

    out_at = out.resolve()
    if out_at in (dataset.resolve(), dataset.resolve().parent / "manifest.json"):
        raise ConfigError(
            f"--out {out}: that is the input dataset {dataset} (or its manifest); name another file"
        )
    if model.resolve() in out_at.parents:
        raise ConfigError(
            f"--out {out}: inside the model folder {model}, whose files it would replace; "
            f"name a file outside it"
        )
    if out_at.exists() and not out_at.is_file() and not out_at.is_dir():
        raise ConfigError(
            f"--out {out}: not a regular file (a FIFO, socket or device); name a regular file"
        )


def _cmd_tune(args: argparse.Namespace) -> None:
    """Optuna study over k and the network sizes; writes the best parameters as a config."""
    from pcpg_dist.api.tune import tune
    from pcpg_dist.common.progress import out as console  # results: stdout
    from pcpg_dist.config.overrides import load_config_with
    from pcpg_dist.orchestration.ray_pool import init_ray
    from pcpg_dist.orchestration.tuning import open_storage, tune_settings

    cfg = load_config_with(args.config, args.overrides)
    storage = open_storage(
        args.optuna_storage, tune_settings(cfg, args.n_trials)
    )  # before Ray starts
    _check_tracking(args)
    init_ray(args.ray_address)
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
    console.print(
        f"best config: {res.best_config}  (run it: pcpg run {shlex.quote(str(res.best_config))}{again})"
    )
    console.print(f"dashboard: uv run optuna-dashboard {res.storage} --host 127.0.0.1")


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


def _cmd_export(args: argparse.Namespace) -> None:
    """`pcpg export FORMAT`: each format's code lives in its own module."""
    if args.what == "onnx":
        from pcpg_dist.api.export import cli_export_onnx

        cli_export_onnx(args)
    elif args.what == "minari":
        from pcpg_dist.domains.trajectories.minari_io import cli_export_minari

        cli_export_minari(args)


def _cmd_domains(args: argparse.Namespace) -> None:
    """The registered domains: built-ins and every `pcpg_dist.domains` entry point."""
    from pcpg_dist.domains import registry

    for name in registry.names():
        kind = "built-in" if name in registry.BUILTIN else "plugin"
        print(f"{name:<16} {kind:<9} {registry.target(name)}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pcpg", description="Play-style-centric agents from gameplay data (PCPG) at scale."
    )
    from pcpg_dist import __version__

    parser.add_argument("--version", action="version", version=f"pcpg {__version__}")
    parser.add_argument(
        "-q",
        "--quiet",
        dest="global_quiet",
        action="store_true",
        help="errors only: no progress bars, no warnings (results still on stdout)",
    )
    parser.add_argument(
        "--verbose", action="store_true", help="also informational logs (pcpg, MLflow)"
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def add_parser(where, name: str, **kw) -> argparse.ArgumentParser:
        """A (sub)command that also takes -q/--quiet and --verbose after its name, like `pcpg -q`."""
        p = where.add_parser(name, **kw)
        # SUPPRESS: absent after the command, the value given before it (or False) stands
        p.add_argument(
            "-q",
            "--quiet",
            action="store_true",
            default=argparse.SUPPRESS,
            help="errors only: no progress bars, no warnings (results still on stdout)",
        )
        p.add_argument(
            "--verbose",
            action="store_true",
            default=argparse.SUPPRESS,
            help="also informational logs (pcpg, MLflow)",
        )
        return p

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--ray-address",
            default=None,
            help="join this Ray cluster (default: $RAY_ADDRESS, else Ray in-process)",
        )

    def overrides(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "overrides",
            nargs="*",
            metavar="KEY=VALUE",
            help="change a setting of the YAML before it is validated, e.g. bc.lr=0.003 "
            "clustering.k=5 (values read as YAML)",
        )

    def tracking(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--tracking-uri",
            default=None,
            help="MLflow tracking URI (default: $MLFLOW_TRACKING_URI, else sqlite:///mlflow.db)",
        )
        p.add_argument("--no-tracking", action="store_true", help="do not log to MLflow")

    p = add_parser(sub, "generate", help="generate the datasets of a config (PBTG on Ray)")
    p.add_argument("config", help="experiment YAML")
    overrides(p)
    p.add_argument("--out", required=True, help="output folder (Parquet files + manifest.json)")
    common(p)
    p.set_defaults(func=_cmd_generate)

    p = add_parser(
        sub, "run", help="run a whole experiment: generate, cluster, rank, train, evaluate, log"
    )
    p.add_argument("config", help="experiment YAML")
    overrides(p)
    p.add_argument(
        "--workdir", default="runs", help="outputs and the resumable cache (default: runs/)"
    )
    tracking(p)
    common(p)
    p.set_defaults(func=_cmd_run)

    p = add_parser(
        sub, "sweep", help="run a grid over config axes: KEY=v1,v2,... (or a start:stop:step range)"
    )
    p.add_argument(
        "config", help="experiment YAML (its optional sweep: section adds grid/zip axes)"
    )
    p.add_argument(
        "axes",
        nargs="*",
        metavar="KEY=VALUES",
        help="an axis (KEY=v1,v2,... or KEY=start:stop:step) or a fixed override (KEY=value)",
    )
    p.add_argument(
        "--workdir", default="runs", help="outputs and the shared cache (default: runs/)"
    )
    tracking(p)
    common(p)
    p.set_defaults(func=_cmd_sweep)

    p = add_parser(
        sub, "cluster", help="Step A only: cluster each environment's trajectories by play-style"
    )
    p.add_argument("config", help="experiment YAML (its clustering section)")
    overrides(p)
    p.add_argument(
        "--out",
        required=True,
        help="output folder: <env>/model, labels.json, metrics.json "
        "(and margins.json from greedy_mix, bag_auto, policy_mix)",
    )
    p.add_argument(
        "--data", default=None, help="dataset folder from `pcpg generate` (default: generate)"
    )
    common(p)
    p.set_defaults(func=_cmd_cluster)

    p = add_parser(
        sub, "classify", help="assign play-styles to trajectories with a fitted clustering model"
    )
    p.add_argument("model", help="model folder written by `pcpg cluster` (<out>/<env>/model)")
    p.add_argument("dataset", help="a dataset Parquet file")
    p.add_argument(
        "--out",
        default=None,
        help="CSV of (trajectory, predicted_style) "
        "(default: ./DATASET_STEM.styles.csv in the current folder)",
    )
    p.set_defaults(func=_cmd_classify)

    p = add_parser(
        sub,
        "report",
        help="write the reproducibility report of a run (HTML + Markdown) or "
        "the page of a sweep (HTML)",
    )
    p.add_argument(
        "target",
        help="a run's output folder (runs/NAME), a sweep's folder (runs/NAME/sweep), an "
        "MLflow run id (a run, a sweep or a sweep's point), or an experiment name "
        "(its newest top-level run: a `pcpg run` or a `pcpg sweep`, never one point)",
    )
    p.add_argument(
        "--out",
        default=None,
        help="folder for report.html/report.md (default: RUN/report; for a sweep, its own folder)",
    )
    p.add_argument(
        "--workdir",
        default="runs",
        help="where a run's summary downloaded from MLflow is kept: "
        "WORKDIR/.report-cache/RUN_ID (default: runs/; unused for a local folder)",
    )
    p.add_argument(
        "--pdf", action="store_true", help="also print report.pdf with a headless Chromium"
    )
    p.add_argument("--tracking-uri", default=None, help="MLflow tracking URI (default: as for run)")
    p.set_defaults(func=_cmd_report)

    p = add_parser(
        sub,
        "reproduce",
        help="rerun a logged run from its recorded config and seeds in a fresh "
        "folder; compare every metric with the logged one (exit 1 if any differs)",
    )
    p.add_argument(
        "run",
        metavar="RUN",
        help="one run: its output folder (runs/NAME, or a sweep's point: "
        "runs/NAME/sweep/points/POINT), an MLflow run id, or an experiment "
        "name (its newest top-level run, as for report); not a whole sweep",
    )
    p.add_argument(
        "--workdir",
        default=None,
        help="fresh (new or empty) folder for the rerun "
        "(default: a new temporary folder, printed at the end)",
    )
    p.add_argument("--rtol", type=float, default=1e-6, help="relative tolerance (default: 1e-6)")
    p.add_argument("--atol", type=float, default=1e-9, help="absolute tolerance (default: 1e-9)")
    p.add_argument("--tracking-uri", default=None, help="MLflow tracking URI (default: as for run)")
    common(p)
    p.set_defaults(func=_cmd_reproduce)

    p = add_parser(sub, "tune", help="tune k and the network sizes with Optuna (trials on Ray)")
    p.add_argument("config", help="experiment YAML (its tuning section: search space, objective)")
    overrides(p)
    p.add_argument(
        "--optuna-storage",
        default=None,
        help="study storage: a journal file path (default: ./optuna_journal.log) or an RDB "
        "URL for teams, e.g. postgresql://user@host:5432/db",
    )
    p.add_argument(
        "--study-name", default=None, help="study name (default: tuning.study_name, else NAME-tune)"
    )
    p.add_argument(
        "--n-trials",
        type=int,
        default=None,
        help="finished trials the study should hold "
        "(default: tuning.n_trials); a rerun with more continues the study",
    )
    p.add_argument(
        "--out",
        default=None,
        help="folder of best_config.yaml, trials.csv, score_vs_k.png "
        "(default: WORKDIR/NAME/tuning, or WORKDIR/NAME/tuning/STUDY for a --study-name other than NAME-tune)",
    )
    p.add_argument("--workdir", default="runs", help="data cache and outputs (default: runs/)")
    tracking(p)
    common(p)
    p.set_defaults(func=_cmd_tune)

    p = add_parser(
        sub, "domains", help="list the registered domains (built-ins and installed plugins)"
    )
    p.set_defaults(func=_cmd_domains)

    p = add_parser(
        sub,
        "export",
        help="export for use outside pcpg: trained agents as ONNX, datasets as Minari",
    )
    p.set_defaults(func=_cmd_export)
    formats = p.add_subparsers(dest="what", required=True, metavar="FORMAT")
    e = add_parser(
        formats,
        "onnx",
        help="one ONNX model per environment + a JSON table of its cells (docs/agents.md)",
    )
    e.add_argument(
        "run",
        help="a run's output folder (runs/NAME), an MLflow run id, or an experiment name "
        "(its newest top-level run, as for report)",
    )
    e.add_argument(
        "--out", required=True, help="folder for agents_<env>.onnx and agents_<env>.json"
    )
    e.add_argument(
        "--workdir",
        default=None,
        help="keep the agents downloaded from MLflow here (default: a temporary folder)",
    )
    e.add_argument("--tracking-uri", default=None, help="MLflow tracking URI (default: as for run)")
    e = add_parser(
        formats,
        "minari",
        help="a pcpg dataset (or a run's cached data) as Minari datasets, one per environment",
    )
    e.add_argument(
        "source",
        metavar="RUN_OR_DATA",
        help="a pcpg dataset folder (with manifest.json) or a run's output folder (runs/NAME)",
    )
    e.add_argument(
        "--out",
        required=True,
        help="Minari datasets root to write into (use it as MINARI_DATASETS_PATH)",
    )
    e.add_argument(
        "--dataset-id",
        default=None,
        help="Minari id namespace/name-vN (default: "
        "pcpg/<folder name>-v0); with several environments each gets namespace/name/<env>-vN",
    )
    return parser


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The parsed command line; ``quiet`` and ``verbose`` hold whether given before or after the command."""
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    # KEY=VALUE items after an option (`pcpg run c.yaml --quiet bc.lr=0.1`) belong to the command
    target = (
        "axes" if hasattr(args, "axes") else "overrides" if hasattr(args, "overrides") else None
    )
    if extra and (target is None or any(e.startswith("-") for e in extra)):
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if extra:
        setattr(args, target, [*getattr(args, target), *extra])
    args.quiet = args.global_quiet or getattr(
        args, "quiet", False
    )  # `pcpg -q run` or `pcpg run -q`
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    from pcpg_dist.common.progress import setup_output

    setup_output(
        quiet=args.quiet,
        verbose=args.verbose,
        private_ray=not (getattr(args, "ray_address", None) or os.environ.get("RAY_ADDRESS")),
    )
    try:
        catch_sigterm()
        args.func(args)
    except PcpgError as e:
        print(f"pcpg: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        # Disk full, permission denied, missing folder: say which file and why, no traceback.
        where = f" {e.filename}" if getattr(e, "filename", None) else ""
        print(f"pcpg: error: cannot access{where}: {e.strerror or e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        from pcpg_dist.common import errors

        terminated = isinstance(e, Terminated) or errors.sigterm_received
        print(
            f"pcpg: interrupted{' (SIGTERM)' if terminated else ''}; rerun the same command to resume",
            file=sys.stderr,
        )
        return 143 if terminated else 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
