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
    from pcpg_dist.api.calls import classify as classify_dataset
    from pcpg_dist.common.progress import out as console  # results: stdout

    # by default into the current folder: the dataset's folder may be a signed `pcpg generate` output
    out = Path(args.out) if args.out else Path(Path(args.dataset).stem + ".styles.csv")
    table = classify_dataset(args.model, args.dataset, out=out, move_features=args.move_features)
    if table.attrs.get("streamed"):  # a streamed run's clustering: the labels are in `out`
        n, sizes = table.attrs["trajectories"], table["trajectories"].tolist()
    else:
        pred = table["predicted_style"].to_numpy()
        n, sizes = len(table), [int((pred == c).sum()) for c in range(int(pred.max()) + 1)]
    console.print(f"{n} trajectories -> {out}; cluster sizes {sizes}")
    if table.attrs.get("style_weights") is not None:
        import pandas as pd

        from pcpg_dist.stages.clustering.style_weights import apart_line

        weights = pd.DataFrame(table.attrs["style_weights"])
        line = apart_line(Path(args.model).name, weights)
        console.print(line, markup=False, highlight=False)
    unknown = table.attrs["unknown_rows"]
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
    if table.attrs["against_styles"] is not None:
        console.print(
            "against the true styles: "
            + ", ".join(
                f"{k} {v:.3f}"
                for k, v in table.attrs["against_styles"].items()
                if isinstance(v, float)
            )
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
