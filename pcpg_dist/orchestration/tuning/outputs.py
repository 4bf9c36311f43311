"""What a finished `pcpg tune` study leaves in its folder: ``best_config.yaml`` (a config
`pcpg run` accepts unchanged), ``trials.csv`` and the score-vs-k figure."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pcpg_dist.config.stages import TARGETS
from pcpg_dist.orchestration.tuning.space import apply_params

if TYPE_CHECKING:
    from pcpg_dist.config import ExperimentConfig


def best_config_data(cfg: ExperimentConfig, params: dict[str, int], where: Path) -> dict[str, Any]:
    """The config with the best parameters, as YAML data for a file in folder ``where``.

    Only what the study's config set, plus the tuned values: defaults stay defaults, so the file
    reads like the one the user wrote. Same name, so ``pcpg run`` of it works in the study's run
    folder and reuses the data the study cached there. No ``tuning`` section; every file or folder
    the config names (layouts, logs) relative to ``where``, so the file can move with its tree.
    """
    import os

    def portable(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: portable(v) for k, v in value.items()}
        if isinstance(value, str) and Path(value).is_absolute() and Path(value).exists():
            return os.path.relpath(value, where.resolve())
        return value

    tuned = apply_params(cfg, params)
    data = cfg.model_dump(mode="json", exclude={"tuning"}, exclude_unset=True)
    for name in params:
        section, key = TARGETS[name]
        value = getattr(getattr(tuned, section), key)
        if value != getattr(
            getattr(cfg, section), key
        ):  # unchanged (a fixed dimension): as the config has it
            data.setdefault(section, {})[key] = value
    if (
        tuned.evaluation.corruption_levels != cfg.evaluation.corruption_levels
    ):  # k = 1: see apply_params
        data.setdefault("evaluation", {})["corruption_levels"] = list(
            tuned.evaluation.corruption_levels
        )
    return {k: portable(v) if isinstance(v, dict) else v for k, v in data.items()}


def write_outputs(
    cfg: ExperimentConfig, study: Any, best_params: dict[str, int], out: Path
) -> Path:
    """``best_config.yaml`` (checked by loading it back), ``trials.csv`` and ``score_vs_k.png``."""
    import yaml

    from pcpg_dist.common.files import atomic_write_bytes
    from pcpg_dist.config import load_config

    out.mkdir(parents=True, exist_ok=True)
    path = out / "best_config.yaml"
    chosen = ", ".join(f"{k}={v}" for k, v in study.best_trial.params.items())
    header = (
        f"# Best parameters of Optuna study {study.study_name!r} ({chosen}),\n"
        f"# score {study.best_value:.4f}: the study's config with only these changed. `pcpg run` it with\n"
        f"# the study's --workdir to reuse the data the study cached under the same name.\n"
    )
    data = best_config_data(cfg, best_params, out)
    atomic_write_bytes(path, (header + yaml.safe_dump(data, sort_keys=False)).encode())
    load_config(path)  # what `pcpg run` will do: fail here, not later, if it is not loadable
    table = study.trials_dataframe(attrs=("number", "state", "value", "params", "user_attrs"))
    atomic_write_bytes(out / "trials.csv", table.to_csv(index=False).encode())
    _plot_score_vs_k(study, out / "score_vs_k.png")
    return path


def _plot_score_vs_k(study: Any, path: Path) -> None:
    """Score and held-out accuracy of every complete trial over k: where the penalty bites."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from optuna.trial import TrialState

    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    k = np.array([t.user_attrs.get("params_full", t.params).get("k", 0) for t in done], float)
    score = np.array([t.value for t in done])
    acc = np.array([t.user_attrs.get("pcpg_accuracy", np.nan) for t in done])
    fig, ax = plt.subplots(figsize=(6, 4.6))
    jitter = np.random.default_rng(0).uniform(
        -0.12, 0.12, len(k)
    )  # seeded: same figure for same study
    ax.scatter(k + jitter, acc, marker="x", color="0.6", label="held-out PCPG accuracy")
    ax.scatter(k + jitter, score, color="C0", label="score = accuracy - penalty (k - 1)")
    for i, kk in enumerate(np.unique(k)):
        ax.plot(
            [kk - 0.3, kk + 0.3],
            [score[k == kk].max()] * 2,
            color="C1",
            label="best score at this k" if i == 0 else None,
        )
    ax.set_xlabel("k (clusters)")
    ax.set_ylabel("accuracy / score")
    ax.set_title(f"{study.study_name}: best k = {study.best_trial.params.get('k', '-')}")
    # below the axes: inside, it hid whichever points fell in its corner
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=2, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
