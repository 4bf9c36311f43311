"""The ``pcpg`` argument parser: one function per group of commands."""

from __future__ import annotations

import argparse

from pcpg_dist.cli import reading, running

QUIET_HELP = "errors only: no progress bars, no warnings (results still on stdout)"


def add_parser(where, name: str, **kw) -> argparse.ArgumentParser:
    """A (sub)command that also takes -q/--quiet and --verbose after its name, like `pcpg -q`."""
    p = where.add_parser(name, **kw)
    # SUPPRESS: absent after the command, the value given before it (or False) stands
    p.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        default=argparse.SUPPRESS,
        help=QUIET_HELP,
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
        help=QUIET_HELP,
    )
    parser.add_argument(
        "--verbose", action="store_true", help="also informational logs (pcpg, MLflow)"
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    for add in (
        _add_run_commands,
        _add_step_commands,
        _add_report_commands,
        _add_tune,
        _add_export,
    ):
        add(sub)
    return parser


def _add_run_commands(sub) -> None:
    p = add_parser(sub, "generate", help="generate the datasets of a config (PBTG on Ray)")
    p.add_argument("config", help="experiment YAML")
    overrides(p)
    p.add_argument("--out", required=True, help="output folder (Parquet files + manifest.json)")
    common(p)
    p.set_defaults(func=running.generate)

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
    p.set_defaults(func=running.run)

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
    p.set_defaults(func=running.sweep)


def _add_step_commands(sub) -> None:
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
    p.set_defaults(func=running.cluster)

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
    p.add_argument(
        "--move-features",
        default=None,
        metavar="MODULE:FUNCTION",
        help="a choice_mix model's move-feature function (the run's clustering.move_features); "
        "pcpg never runs code a model file names",
    )
    p.set_defaults(func=reading.classify)


def _add_report_commands(sub) -> None:
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
    p.set_defaults(func=reading.report)

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
    p.add_argument(
        "--allow-changed-data",
        action="store_true",
        help="rerun even where the data's digest differs from the logged run's (by default "
        "that is said in one line and nothing reruns)",
    )
    common(p)
    p.set_defaults(func=reading.reproduce)


def _add_tune(sub) -> None:
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
    p.set_defaults(func=running.tune)


def _add_export(sub) -> None:
    p = add_parser(
        sub, "domains", help="list the registered domains (built-ins and installed plugins)"
    )
    p.set_defaults(func=reading.domains)

    p = add_parser(
        sub,
        "export",
        help="export for use outside pcpg: trained agents as ONNX, datasets as Minari",
    )
    p.set_defaults(func=reading.export)
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
