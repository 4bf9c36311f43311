"""pcpg from Python (a notebook, a script): the commands as functions, with the same validation
and one-line errors as the CLI, raised as :class:`~pcpg_dist.common.errors.PcpgError` (never
``SystemExit``). Nothing heavy is imported until a function is called."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pcpg_dist.config import ExperimentConfig


def config_of(config: str | Path | dict | ExperimentConfig, overrides: list[str] | None = None):
    """A validated config from a YAML path, a mapping or a config, ``key=value`` overrides applied."""
    from pcpg_dist.config.experiment import parse_config
    from pcpg_dist.config.overrides import apply_overrides, load_config_with, parse_overrides

    if isinstance(config, str | Path):
        return load_config_with(config, overrides)
    raw = config.model_dump(mode="json") if isinstance(config, ExperimentConfig) else dict(config)
    return parse_config(apply_overrides(raw, parse_overrides(overrides or [])), source="<python>")


def run(
    config: str | Path | dict | ExperimentConfig,
    overrides: list[str] | None = None,
    *,
    workdir: str | Path = "runs",
    tracking_uri: str | None = None,
    track: bool = True,
    show_progress: bool = True,
    in_process: bool = False,
) -> Any:
    """`pcpg run` from Python; returns its :class:`~pcpg_dist.orchestration.points.RunResult`.

    Ray starts privately on first use (or joins ``RAY_ADDRESS``); ``in_process=True`` runs every
    job in this process instead, with no Ray at all."""
    from pcpg_dist.api.run import run_experiment

    cfg = config_of(config, overrides)
    return run_experiment(
        cfg,
        workdir=Path(workdir),
        tracking_uri=tracking_uri,
        track=track,
        show_progress=show_progress,
        executor=_executor(in_process),
    )


def cluster(
    config: str | Path | dict | ExperimentConfig,
    out: str | Path,
    overrides: list[str] | None = None,
    *,
    data: str | Path | None = None,
    show_progress: bool = True,
    in_process: bool = False,
) -> dict[str, dict]:
    """`pcpg cluster` from Python: each environment's labels, margins and metrics."""
    from pcpg_dist.api.cluster import cluster as cluster_units

    cfg = config_of(config, overrides)
    executor = _executor(in_process)
    return cluster_units(cfg, Path(out), Path(data) if data else None, show_progress, executor)


def sweep(
    config: str | Path | dict | ExperimentConfig,
    axes: dict[str, list] | list[str] | None = None,
    overrides: list[str] | None = None,
    *,
    workdir: str | Path = "runs",
    tracking_uri: str | None = None,
    track: bool = True,
    show_progress: bool = True,
) -> Any:
    """`pcpg sweep` from Python: every point of the grid ``axes`` (``{key: [values]}``, added to
    the ``grid:`` of the config's own ``sweep:`` section; or the CLI's ``"key=v1,v2"`` strings), on Ray;
    returns its :class:`~pcpg_dist.api.sweep.SweepResult` (``rows``: one per point, ``out_dir``:
    its table, report and figures). A finished point is reused, never rerun."""
    from pcpg_dist.api.sweep import run_sweep
    from pcpg_dist.config.overrides import read_raw
    from pcpg_dist.orchestration.ray_pool import init_ray

    grid = axes if isinstance(axes, dict) else {}
    args = [] if isinstance(axes, dict) else list(axes or [])
    if isinstance(config, str | Path) and not grid:
        plan_config: str | Path | dict = config
    else:
        if isinstance(config, str | Path):
            raw, section = read_raw(config)
            raw = {**raw, **({"sweep": section} if section else {})}
        elif isinstance(config, ExperimentConfig):
            raw = config.model_dump(mode="json")
        else:
            raw = dict(config)
        section = dict(raw.get("sweep") or {})
        section["grid"] = {**(section.get("grid") or {}), **grid}
        plan_config = {**raw, "sweep": section}
    init_ray()
    return run_sweep(
        plan_config,
        args,
        overrides,
        workdir=Path(workdir),
        tracking_uri=tracking_uri,
        track=track,
        show_progress=show_progress,
        command="pcpg_dist.sweep(...)",
    )


def classify(
    model: str | Path,
    dataset: str | Path | Any,
    *,
    out: str | Path | None = None,
    move_features: str | None = None,
) -> Any:
    """`pcpg classify` from Python: each trajectory's style under a fitted clustering model
    (``pcpg cluster``'s ``model.json``), as a pandas table (``trajectory``, ``predicted_style``);
    ``dataset``: a dataset folder or a :class:`~pcpg_dist.dataset.Dataset`. With ``out`` the table
    is also written there as CSV (never over the dataset or the model, never inside a run).

    ``table.attrs`` holds ``unknown_rows`` (the share of rows in states the model was not fitted
    on; None where the model has no such notion), ``against_styles`` (accuracy and agreement
    with the dataset's true styles where it has them, else None) and ``style_weights`` (what
    each cluster of a ``choice_mix`` model weighs, column by column: ``feature``, ``k0`` ...;
    else None).

    With a streamed run's clustering (``RUN/summary/model_seed<S>``) ``dataset`` is a Parquet log
    of any size, labelled block by block into ``out`` (required), and the table holds the cluster
    sizes (:func:`pcpg_dist.api.streamed.classify_streamed`). A ``choice_mix`` model (a run with
    ``clustering.move_features``) needs that same ``move_features``: a model file never names the
    code pcpg runs."""
    import pandas as pd

    from pcpg_dist.common.files import atomic_write_bytes
    from pcpg_dist.dataset import Dataset, load_dataset
    from pcpg_dist.stages.clustering import clustering_metrics, load_model
    from pcpg_dist.stages.clustering.style_weights import style_weights_of
    from pcpg_dist.stages.streamed.model import is_streamed_model

    if out is not None:
        from pcpg_dist.common.run_folders import check_outside_run

        check_classify_out(
            Path(out), Path(model), None if isinstance(dataset, Dataset) else Path(dataset)
        )
        check_outside_run(Path(out))
    if not isinstance(dataset, Dataset) and is_streamed_model(Path(model)):
        from pcpg_dist.api.streamed import classify_streamed

        return classify_streamed(Path(model), Path(dataset), None if out is None else Path(out))
    fitted = load_model(Path(model), move_features=move_features)
    ds = dataset if isinstance(dataset, Dataset) else load_dataset(Path(dataset))
    pred = fitted.predict(ds)
    # the logs' own ids where they were not integers (pcpg numbers those in sorted order)
    ids = ds.trajectory_ids if ds.source_ids is None else ds.source_ids
    table = pd.DataFrame({"trajectory": ids, "predicted_style": pred})
    table.attrs["unknown_rows"] = fitted.unknown_rows(ds)
    labelled = (ds.styles >= 0).all()
    table.attrs["against_styles"] = clustering_metrics(ds.styles, pred) if labelled else None
    weights = style_weights_of(fitted)  # choice_mix: what each cluster weighs (plain lists)
    table.attrs["style_weights"] = None if weights is None else weights.to_dict(orient="list")
    if out is not None:
        atomic_write_bytes(Path(out), table.to_csv(index=False).encode())
    return table


def check_classify_out(out: Path, model: Path, dataset: Path | None) -> None:
    """The labels never overwrite the inputs: the dataset (or its manifest), a file of the model."""
    from pcpg_dist.common.errors import ConfigError

    out_at = out.resolve()
    if dataset is not None and out_at in (
        dataset.resolve(),
        dataset.resolve().parent / "manifest.json",
    ):
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


def _executor(in_process: bool):
    """This process for every job, or Ray (started privately on first use, or RAY_ADDRESS)."""
    from pcpg_dist.orchestration.executors import LocalExecutor, RayExecutor

    if in_process:
        return LocalExecutor()
    from pcpg_dist.orchestration.ray_pool import init_ray

    init_ray()
    return RayExecutor()
