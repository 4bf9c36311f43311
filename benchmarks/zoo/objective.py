"""Which partition does a mixture of policies prefer, the true styles or the default's? Every game.

    uv run python -m benchmarks.zoo.objective [GAME ...] [--seed 0] [--workers 2] [--out F]
    uv run python -m benchmarks.zoo.objective --extend F   # add EM from the styles to F's rows
    uv run python -m benchmarks.zoo.objective --read F     # print F's table again

For each game: the default clustering (``bag_auto``, k = its styles, its confidence refits
included, one torch thread) at ``--seed``, and the true styles. Each partition is scored as
``benchmarks.zoo.search`` scores one: a fresh policy mixture fitted to it for ``--steps`` Adam
steps (to a sample of at most ``--rows`` steps on large logs), then the mean log-likelihood a
step of each trajectory's actions under its own cluster's policy, in-sample (``fit``) and on
trajectories left out of the fit (``held_out``, 2-fold), averaged over ``--score-seeds``
network seeds. Both partitions get the same network seeds, folds, inputs and training, so
neither is favoured and their difference is paired by seed.

A measure favours the styles (or the default's partition) where the mean difference is more than
twice its standard error over the scoring seeds; within that it is a tie (the scoring networks'
own spread: highway's held-out score moves by 0.15 nats a step between seeds). Where some
measure favours the styles and none the default's, the objective the default climbs (the
actions' likelihood under k policies) prefers the styles, and its gap is its **search**'s.
Where some favours the default's partition and none the styles, no search on that objective
would move towards the styles: the gap is the **objective**'s (the styles are not the k-policy
partition that explains the play best). The held-out games are printed apart; nothing here
chooses a setting.

Each game's gap at ``--seed`` (the ceiling, its supervised panel's best member, less the
default) is split in two: the **model class**'s part, the ceiling less the panel's policy
classifier (k policies of policy_mix's own kind trained on the styles: what its model reaches
given the labels), and the **label-free** part, that classifier less the default. The panels
come from the one table's results (``--panels``).
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from benchmarks.zoo.common import game_names, load_game
from benchmarks.zoo.confidence import WITHIN

MEASURES = ("fit", "held_out")


def scored(ds, partition: np.ndarray, k: int, steps: int, rows: int, score_seeds: int) -> dict:
    """``partition``'s :func:`.search.partition_scores` at scoring seeds 0..``score_seeds`` - 1:
    {measure: [score at each seed]}."""
    from benchmarks.zoo.search import partition_scores

    runs = [partition_scores(ds, partition, k, steps, s, rows) for s in range(score_seeds)]
    return {key: [r[key] for r in runs] for key in MEASURES}


def objective_row(name: str, seed: int, steps: int, rows: int, score_seeds: int) -> dict:
    """The default's partition of ``name`` at ``seed`` and the styles, each scored."""
    from benchmarks.zoo.check import labelled_dataset
    from pcpg_dist.common.devices import set_threads
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import cluster, clustering_metrics

    set_threads(1)
    game = load_game(name)
    ds = labelled_dataset(name, False)
    k = len(game.styles)
    t0 = time.perf_counter()
    labels = cluster(ds, ClusterConfig(k=k), seed).labels
    fit_seconds = time.perf_counter() - t0
    truth = np.asarray(ds.styles, np.int64)
    t0 = time.perf_counter()
    default, styles = (scored(ds, x, k, steps, rows, score_seeds) for x in (labels, truth))
    return {
        "game": name,
        "held_out": game.held_out,
        "blind": game.blind,
        "seed": seed,
        "accuracy": float(clustering_metrics(truth, labels)["accuracy"]),
        "default": default,  # per scoring seed
        "styles": styles,
        "labels": labels.tolist(),
        "fit_seconds": fit_seconds,
        "score_seconds": time.perf_counter() - t0,
    }


def from_styles_row(name: str, seed: int, steps: int, rows: int, score_seeds: int) -> dict:
    """policy_mix's EM started from the true styles (:func:`.common.policy_mix_from`) at
    ``seed``: where it ends, how far that is from the styles, and its scores. Its partition and
    the default's are both fixed points of the same EM, so neither owes its score to having been
    chosen by the likelihood it is scored on, as the default's partition does against the styles
    themselves."""
    from benchmarks.zoo.check import labelled_dataset
    from benchmarks.zoo.common import policy_mix_from
    from pcpg_dist.common.devices import set_threads
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import clustering_metrics
    from pcpg_dist.stages.clustering.states import checked_sequences

    set_threads(1)
    ds = labelled_dataset(name, False)
    k = len(load_game(name).styles)
    truth = np.asarray(ds.styles, np.int64)
    states, offsets = checked_sequences(ds)
    cfg = ClusterConfig(k=k, method="policy_mix")
    labels = policy_mix_from(ds, states, offsets, cfg, seed, truth)
    return {
        "game": name,
        "from_styles": scored(ds, labels, k, steps, rows, score_seeds),
        "from_styles_accuracy": float(clustering_metrics(truth, labels)["accuracy"]),
    }


def favours(row: dict, measure: str, against: str = "styles") -> tuple[float, str]:
    """(mean of ``against`` - default over the scoring seeds, "styles" / "default" / "tie"):
    which partition ``measure`` favours beyond twice the standard error of the paired
    difference (``against``: the styles themselves, or EM's end from them, "from_styles")."""
    diff = np.subtract(row[against][measure], row["default"][measure])
    mean = float(diff.mean())
    se = float(diff.std(ddof=1) / np.sqrt(len(diff))) if len(diff) > 1 else 0.0
    return mean, "styles" if mean > 2 * se else "default" if mean < -2 * se else "tie"


def reading(row: dict, gap: float | None) -> str:
    """Whose limit the row shows (module doc): "at the ceiling", "search", "objective",
    "undetermined" (ties on both measures) or "mixed" (one measure each way); judged against
    EM's end from the styles where the row has it, else against the styles themselves."""
    if gap is not None and gap <= WITHIN:
        return "at the ceiling"
    against = "from_styles" if "from_styles" in row else "styles"
    sides = {favours(row, m, against)[1] for m in MEASURES} - {"tie"}
    if not sides:
        return "undetermined"
    if len(sides) == 2:
        return "mixed"
    return "search" if sides == {"styles"} else "objective"


def panels(path: Path | None, seed: int) -> dict[str, dict]:
    """Each game's supervised panel (:func:`.ceiling.ceiling_panel`) from the ``seed`` rows of a
    ``benchmarks.zoo.confidence`` results file, if given."""
    if path is None or not path.exists():
        return {}
    rows = json.loads(path.read_text())["rows"]
    return {r["game"]: r["panel"] for r in rows if r["seed"] == seed}


def split_gap(row: dict, panel: dict | None) -> tuple[float, float, float] | None:
    """(ceiling, k policies given the styles, the gap's model-class part): the ceiling is the
    panel's best member; the model class's own ceiling is its policy classifier's (with the time
    step or without), the policy mixture policy_mix fits given the styles; the rest of the gap
    (that one less the default) is what the label-free fit loses."""
    if not panel:
        return None
    ceiling = max(panel.values())
    policy = max(panel["policy_likelihood"], panel["policy_time_likelihood"])
    return ceiling, policy, ceiling - policy


def gap_of(row: dict, panel: dict | None) -> float | None:
    """The row's gap to its ceiling (:func:`split_gap`), None without a panel."""
    split = split_gap(row, panel)
    return None if split is None else split[0] - row["accuracy"]


def versus(row: dict, against: str) -> str:
    """The two measures' paired differences of ``against`` less the default, as a table cell."""
    cells = []
    for m in MEASURES:
        diff, side = favours(row, m, against)
        cells.append(f"{diff:+.4f} ({side})")
    return " / ".join(cells)


def print_rows(rows: list[dict], panels: dict[str, dict]) -> None:
    """The markdown table of the notebook's nineteenth session (each row's reading derived here,
    not stored: it follows the file's scores and the panels)."""
    print(
        "| game | ceiling | k policies given the styles | default | gap: model class + "
        "label-free | styles less default: fit / held out | EM from the styles: accuracy; "
        "less default: fit / held out | label-free limit |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for row in sorted(rows, key=lambda r: (r["held_out"], r["game"])):
        split = split_gap(row, panels.get(row["game"]))
        gap = gap_of(row, panels.get(row["game"]))
        name = row["game"] + (" (held out)" if row["held_out"] else "")
        parts = ["", "", f"{row['accuracy']:.3f}", ""]
        if split is not None:
            ceiling, policy, model = split
            label_free = policy - row["accuracy"]
            parts = [
                f"{ceiling:.3f}",
                f"{policy:.3f}",
                f"{row['accuracy']:.3f}",
                f"{gap:+.3f} = {model:+.3f} + {label_free:+.3f}",
            ]
        parts.append(versus(row, "styles"))
        em = ""
        if "from_styles" in row:
            em = f"{row['from_styles_accuracy']:.3f}; {versus(row, 'from_styles')}"
        print(f"| {name} | {' | '.join([*parts, em])} | {reading(row, gap)} |", flush=True)


def extend(path: Path, args: argparse.Namespace) -> dict:
    """Add EM from the styles (:func:`from_styles_row`) to every row of the results file
    ``path`` whose game is not at its ceiling (by the panels of ``args.panels``), in place;
    returns the file's contents."""
    saved = json.loads(path.read_text())
    seed, steps, rows, score_seeds = (
        saved["args"][key] for key in ("seed", "steps", "rows", "score_seeds")
    )
    known = panels(args.panels, seed)
    todo = []
    for r in saved["rows"]:
        gap = gap_of(r, known.get(r["game"]))
        if gap is not None and gap > WITHIN:
            todo.append(r["game"])
    with ProcessPoolExecutor(args.workers) as pool:
        jobs = [pool.submit(from_styles_row, n, seed, steps, rows, score_seeds) for n in todo]
        found = {row["game"]: row for row in (job.result() for job in as_completed(jobs))}
    for r in saved["rows"]:
        r.update(found.get(r["game"], {}))
    path.write_text(json.dumps(saved, indent=1))
    return saved


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("games", nargs="*")
    ap.add_argument("--seed", type=int, default=0, help="the default clustering's seed")
    ap.add_argument("--steps", type=int, default=400, help="Adam steps of each scoring fit")
    ap.add_argument("--rows", type=int, default=32768, help="steps a scoring fit sees at most")
    ap.add_argument("--score-seeds", type=int, default=4, help="scoring networks per partition")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument(
        "--panels",
        type=Path,
        default=Path("benchmarks/zoo/confidence_results.json"),
        help="the one table's confidence results: each game's supervised panel",
    )
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--read", type=Path, default=None, help="print a results file's table again")
    ap.add_argument(
        "--extend",
        type=Path,
        default=None,
        help="add EM from the styles to a results file's games that are not at their ceiling "
        "(with the file's own seed and scoring settings)",
    )
    args = ap.parse_args()
    if args.extend or args.read:
        saved = extend(args.extend, args) if args.extend else json.loads(args.read.read_text())
        print_rows(saved["rows"], panels(args.panels, saved["args"]["seed"]))
        return
    names = args.games or game_names()
    with ProcessPoolExecutor(args.workers) as pool:
        jobs = [
            pool.submit(objective_row, n, args.seed, args.steps, args.rows, args.score_seeds)
            for n in names
        ]
        rows = [job.result() for job in as_completed(jobs)]
    print_rows(rows, panels(args.panels, args.seed))
    if args.out:
        settings = {key: str(v) if isinstance(v, Path) else v for key, v in vars(args).items()}
        args.out.write_text(json.dumps({"args": settings, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
