"""The ``pcpg`` command line. Every user mistake prints one line and exits with code 2."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pcpg_dist.errors import PcpgError


def _cmd_generate(args: argparse.Namespace) -> None:
    from pcpg_dist.config import load_config
    from pcpg_dist.generate import generate_to
    from pcpg_dist.progress import console
    from pcpg_dist.ray_utils import init_ray

    cfg = load_config(args.config)
    init_ray(args.ray_address)
    datasets = generate_to(cfg, Path(args.out), show_progress=not args.quiet)
    for env, ds in datasets.items():
        console.print(f"{env}: {ds.n_trajectories} trajectories, {ds.n_rows} rows, "
                      f"success {ds.success.mean():.3f}, mean length {ds.lengths.mean():.1f}")
    console.print(f"wrote {args.out}/manifest.json")


def _check_tracking(args: argparse.Namespace) -> None:
    """Fail in seconds on a dead MLflow server, before Ray and torch start."""
    if not args.no_tracking:
        from pcpg_dist.tracking import check_reachable, default_tracking_uri

        check_reachable(args.tracking_uri or default_tracking_uri())


def _cmd_run(args: argparse.Namespace) -> None:
    from pcpg_dist.config import load_config
    from pcpg_dist.progress import console
    from pcpg_dist.ray_utils import init_ray
    from pcpg_dist.runner import run_experiment
    from pcpg_dist.summary import print_summary

    cfg = load_config(args.config)
    _check_tracking(args)
    init_ray(args.ray_address)
    result = run_experiment(cfg, workdir=Path(args.workdir), tracking_uri=args.tracking_uri,
                            track=not args.no_tracking, show_progress=not args.quiet,
                            command=" ".join(["pcpg", *sys.argv[1:]]))
    print_summary(result, console)
    if result.parent_run_id:
        from pcpg_dist.tracking import default_tracking_uri

        uri = args.tracking_uri or default_tracking_uri()
        view = (f"uv run mlflow ui --backend-store-uri {uri}" if uri.startswith("sqlite:") else f"open {uri}")
        console.print(f"MLflow parent run: {result.parent_run_id}  (view: {view})")
    console.print(f"outputs: {result.out_dir}/summary")
    if getattr(result, "report", None):
        console.print(f"report: {result.report}")


def _cmd_report(args: argparse.Namespace) -> None:
    from pcpg_dist.progress import console
    from pcpg_dist.report import render, resolve_summary

    summary, run_id = resolve_summary(args.target, args.tracking_uri, Path(args.workdir))
    out = Path(args.out) if args.out else summary.parent / "report"
    html_path, md_path = render(summary, out)
    console.print(f"report: {html_path}\nmarkdown: {md_path}")


def _cmd_cluster(args: argparse.Namespace) -> None:
    """Step A alone: one clustering per environment on Ray; saves models + labels."""
    import json

    from pcpg_dist.config import load_config
    from pcpg_dist.dataset import confined, load_datasets
    from pcpg_dist.generate import generate_to
    from pcpg_dist.progress import console
    from pcpg_dist.ray_utils import init_ray, run_tasks
    from pcpg_dist.runner import cluster_task

    cfg = load_config(args.config)
    init_ray(args.ray_address)
    out = Path(args.out)
    if args.data:
        datasets = load_datasets(Path(args.data))
    else:
        datasets = generate_to(cfg, out / "data", show_progress=not args.quiet)
    # the same units (split, per-level scaling, valid sets) as `pcpg run` clusters
    units = {u.name: u for u in cfg.domain_object.units(cfg, datasets)}
    envs = list(units)
    folders = {e: confined(out, e, "unit name") for e in envs}
    results = run_tasks(cluster_task, [(units[e], cfg.clustering, cfg.seed, cfg.runner.cpus_per_task,
                                        str(folders[e])) for e in envs],
                        "Step A: clustering", num_cpus=cfg.runner.cpus_per_task, show_progress=not args.quiet)
    for env, res in zip(envs, results, strict=True):
        (folders[env] / "labels.json").write_text(json.dumps(res["labels"]))
        (folders[env] / "metrics.json").write_text(json.dumps(res["metrics"], indent=1))
        shown = ", ".join(f"{k.split('/')[1]} {v:.3f}" for k, v in res["metrics"].items()
                          if k.split("/")[1] in ("ari", "nmi", "accuracy", "silhouette", "fit_seconds"))
        console.print(f"{env}: {shown}  model: {folders[env] / 'model'}")


def _cmd_classify(args: argparse.Namespace) -> None:
    """Label trajectories of a dataset with a fitted clustering model's styles."""
    import pandas as pd

    from pcpg_dist.clustering import clustering_metrics, load_model
    from pcpg_dist.dataset import atomic_write_bytes, load_dataset
    from pcpg_dist.progress import console

    model = load_model(Path(args.model))
    ds = load_dataset(Path(args.dataset))
    pred = model.predict(ds)
    out = Path(args.out) if args.out else Path(args.dataset).with_suffix(".styles.csv")
    table = pd.DataFrame({"trajectory": ds.trajectory_ids, "predicted_style": pred})
    atomic_write_bytes(out, table.to_csv(index=False).encode())
    console.print(f"{ds.n_trajectories} trajectories -> {out}; cluster sizes "
                  f"{[int((pred == c).sum()) for c in range(int(pred.max()) + 1)]}")
    if (ds.styles >= 0).all():
        m = clustering_metrics(ds.styles, pred)
        console.print("against the true styles: " + ", ".join(f"{k} {v:.3f}" for k, v in m.items()
                                                             if isinstance(v, float)))


def _cmd_tune(args: argparse.Namespace) -> None:
    """Optuna study over k and the network sizes; writes the best parameters as a config."""
    from pcpg_dist.config import load_config
    from pcpg_dist.progress import console
    from pcpg_dist.ray_utils import init_ray
    from pcpg_dist.tuning import run_study

    cfg = load_config(args.config)
    _check_tracking(args)
    init_ray(args.ray_address)
    res = run_study(cfg, storage_url=args.optuna_storage, workdir=Path(args.workdir),
                    tracking_uri=args.tracking_uri, track=not args.no_tracking,
                    show_progress=not args.quiet, n_trials=args.n_trials, study_name=args.study_name,
                    out=Path(args.out) if args.out else None)
    shown = ", ".join(f"{k}={v}" for k, v in res.best_params.items())
    console.print(f"study {res.study_name}: trials {res.n_trials}; best score {res.best_value:.4f} with {shown}")
    if res.failed_stale:
        console.print(f"failed and re-queued stale trials {res.failed_stale} (their driver had stopped)")
    console.print(f"best config: {res.best_config}  (run it: pcpg run {res.best_config})")
    console.print(f"dashboard: uv run optuna-dashboard {res.storage} --host 127.0.0.1")


def _cmd_export(args: argparse.Namespace) -> None:
    """`pcpg export FORMAT`: each format's code lives in its own module."""
    if args.what == "onnx":
        from pcpg_dist.onnx_export import cli_export_onnx

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
        prog="pcpg", description="Play-style-centric agents from gameplay data (PCPG) at scale.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--ray-address", default=None,
                       help="join this Ray cluster (default: $RAY_ADDRESS, else Ray in-process)")
        p.add_argument("--quiet", action="store_true", help="no progress bars")

    def tracking(p: argparse.ArgumentParser) -> None:
        p.add_argument("--tracking-uri", default=None,
                       help="MLflow tracking URI (default: $MLFLOW_TRACKING_URI, else sqlite:///mlflow.db)")
        p.add_argument("--no-tracking", action="store_true", help="do not log to MLflow")

    p = sub.add_parser("generate", help="generate the datasets of a config (PBTG on Ray)")
    p.add_argument("config", help="experiment YAML")
    p.add_argument("--out", required=True, help="output folder (Parquet files + manifest.json)")
    common(p)
    p.set_defaults(func=_cmd_generate)

    p = sub.add_parser("run", help="run a whole experiment: generate, cluster, rank, train, evaluate, log")
    p.add_argument("config", help="experiment YAML")
    p.add_argument("--workdir", default="runs", help="outputs and the resumable cache (default: runs/)")
    tracking(p)
    common(p)
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("cluster", help="Step A only: cluster each environment's trajectories by play-style")
    p.add_argument("config", help="experiment YAML (its clustering section)")
    p.add_argument("--out", required=True, help="output folder: <env>/model, labels.json, metrics.json")
    p.add_argument("--data", default=None, help="dataset folder from `pcpg generate` (default: generate)")
    common(p)
    p.set_defaults(func=_cmd_cluster)

    p = sub.add_parser("classify", help="assign play-styles to trajectories with a fitted clustering model")
    p.add_argument("model", help="model folder written by `pcpg cluster` (<out>/<env>/model)")
    p.add_argument("dataset", help="a dataset Parquet file")
    p.add_argument("--out", default=None, help="CSV of (trajectory, predicted_style)")
    p.set_defaults(func=_cmd_classify)

    p = sub.add_parser("report", help="write the reproducibility report of a sweep (HTML + Markdown)")
    p.add_argument("target", help="MLflow run id, experiment name, or a run's output folder (runs/NAME)")
    p.add_argument("--out", default=None, help="folder for report.html/report.md (default: beside the summary)")
    p.add_argument("--workdir", default="runs", help="where downloaded artifacts are kept")
    p.add_argument("--tracking-uri", default=None, help="MLflow tracking URI (default: as for run)")
    p.set_defaults(func=_cmd_report)

    p = sub.add_parser("tune", help="tune k and the network sizes with Optuna (trials on Ray)")
    p.add_argument("config", help="experiment YAML (its tuning section: search space, objective)")
    p.add_argument("--optuna-storage", default=None,
                   help="study storage: a journal file path (default: ./optuna_journal.log) or an RDB "
                        "URL for teams, e.g. postgresql://user@host:5432/db")
    p.add_argument("--study-name", default=None, help="study name (default: tuning.study_name, else NAME-tune)")
    p.add_argument("--n-trials", type=int, default=None, help="finished trials the study should hold "
                   "(default: tuning.n_trials); a rerun with more continues the study")
    p.add_argument("--out", default=None, help="folder of best_config.yaml, trials.csv, score_vs_k.png "
                   "(default: WORKDIR/NAME/tuning)")
    p.add_argument("--workdir", default="runs", help="data cache and outputs (default: runs/)")
    tracking(p)
    common(p)
    p.set_defaults(func=_cmd_tune)

    p = sub.add_parser("domains", help="list the registered domains (built-ins and installed plugins)")
    p.set_defaults(func=_cmd_domains)

    p = sub.add_parser("export", help="export trained agents for use outside pcpg (ONNX)")
    p.set_defaults(func=_cmd_export)
    formats = p.add_subparsers(dest="what", required=True, metavar="FORMAT")
    e = formats.add_parser("onnx", help="one ONNX model per environment + a JSON table of its cells "
                                        "(docs/agents.md)")
    e.add_argument("run", help="a run's output folder (runs/NAME), an MLflow run id, or an experiment name")
    e.add_argument("--out", required=True, help="folder for agents_<env>.onnx and agents_<env>.json")
    e.add_argument("--workdir", default=None, help="keep the agents downloaded from MLflow here "
                   "(default: a temporary folder)")
    e.add_argument("--tracking-uri", default=None, help="MLflow tracking URI (default: as for run)")
    e = formats.add_parser("minari", help="a pcpg dataset (or a run's cached data) as Minari datasets, "
                                          "one per environment")
    e.add_argument("source", metavar="RUN_OR_DATA",
                   help="a pcpg dataset folder (with manifest.json) or a run's output folder (runs/NAME)")
    e.add_argument("--out", required=True, help="Minari datasets root to write into (use it as "
                   "MINARI_DATASETS_PATH)")
    e.add_argument("--dataset-id", default=None, help="Minari id namespace/name-vN (default: "
                   "pcpg/<folder name>-v0); with several environments each gets namespace/name/<env>-vN")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        args.func(args)
    except PcpgError as e:
        print(f"pcpg: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        # Disk full, permission denied, missing folder: say which file and why, no traceback.
        where = f" {e.filename}" if getattr(e, "filename", None) else ""
        print(f"pcpg: error: cannot access{where}: {e.strerror or e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pcpg: interrupted; rerun the same command to resume", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
