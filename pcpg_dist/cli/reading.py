"""The commands that read what runs left: report, reproduce, classify, export, domains."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path


def report(args: argparse.Namespace) -> None:
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


def reproduce(args: argparse.Namespace) -> None:
    """Rerun a logged run in a fresh folder; exit 1 when some metric differs."""
    from pcpg_dist.api.reproduce import cli_reproduce

    code = cli_reproduce(args)
    if code:
        raise SystemExit(code)


def classify(args: argparse.Namespace) -> None:
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


def export(args: argparse.Namespace) -> None:
    """`pcpg export FORMAT`: each format's code lives in its own module."""
    if args.what == "onnx":
        from pcpg_dist.api.export import cli_export_onnx

        cli_export_onnx(args)
    elif args.what == "minari":
        from pcpg_dist.domains.trajectories.minari_io import cli_export_minari

        cli_export_minari(args)


def domains(args: argparse.Namespace) -> None:
    """The registered domains: built-ins and every `pcpg_dist.domains` entry point."""
    from pcpg_dist.domains import registry

    for name in registry.names():
        kind = "built-in" if name in registry.BUILTIN else "plugin"
        print(f"{name:<16} {kind:<9} {registry.target(name)}")
