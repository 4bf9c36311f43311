"""docs/zoo.md's one table: every zoo game's kind, ceiling, each method, the default, its gap, its
label-free confidence and seconds, from the JSON of :mod:`.evaluate` and of :mod:`.confidence`
(same seed and settings), design games first, then the held-out ones.

    uv run python -m benchmarks.zoo.evaluate --out zoo.json
    uv run python -m benchmarks.zoo.confidence --out zoo_confidence.json
    uv run python -m benchmarks.zoo.table zoo.json zoo_confidence.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from benchmarks.zoo.common import load_game
from benchmarks.zoo.confidence import WITHIN
from benchmarks.zoo.evaluate import METHODS


def per_game(confidence: list[dict]) -> dict[str, dict]:
    """Each game's confidence rows joined over their seeds: the mean accuracy, gap, stability and
    seconds, the range of the accuracy, and the verdicts seed by seed."""
    out = {}
    for game in {r["game"] for r in confidence}:
        mine = sorted((r for r in confidence if r["game"] == game), key=lambda r: r.get("seed", 0))
        joined = dict(mine[0])
        for key in ("accuracy", "gap", "stability", "fit_seconds", "confidence_seconds"):
            joined[key] = float(np.mean([r[key] for r in mine]))
        joined["seeds"] = len(mine)
        joined["low"], joined["high"] = (
            min(r["accuracy"] for r in mine),
            max(r["accuracy"] for r in mine),
        )
        verdicts = [r["verdict"] for r in mine]
        joined["verdict"] = ", ".join(
            v + (f" ({verdicts.count(v)} of {len(mine)})" if len(mine) > 1 else "")
            for v in dict.fromkeys(verdicts)  # in the seeds' order
        )
        for key in ("fell_back", "chose_policy_mix", "chose_policy_time"):  # the seeds' majority
            joined[key] = 2 * sum(bool(r.get(key)) for r in mine) > len(mine)
        out[game] = joined
    return out


def table(evaluated: list[dict], confidence: list[dict]) -> str:
    conf = per_game(confidence)
    head = (
        "| game | kinds | n | ceiling | "
        + " | ".join(f"`{m}`" for m in METHODS)
        + " | default | gap | stability | verdict | s (fit + confidence) |\n|"
        + "---|" * (len(METHODS) + 9)
    )
    parts = []
    for title, held in (("Design games", False), ("Held-out games", True)):
        rows = sorted((r for r in evaluated if r["held_out"] == held), key=lambda r: r["game"])
        lines = []
        for r in rows:
            c = conf[r["game"]]
            accs = " | ".join(f"{r['methods'][m]['accuracy']:.3f}" for m in METHODS)
            ran = "policy_mix" if c["fell_back"] or c.get("chose_policy_mix") else "greedy_mix"
            ran += " with time" if c.get("chose_policy_time") else ""
            ceiling = c.get("ceiling", r["ceiling"])  # the panel of the confidence run
            name = r["game"] + (" (blind)" if load_game(r["game"]).blind else "")
            lines.append(
                f"| {name} | {', '.join(r['kinds'])} | {r['trajectories']} | "
                f"{ceiling:.3f} | {accs} | {c['accuracy']:.3f} ({spread(c)}{ran}) | {c['gap']:+.3f} | "
                f"{c['stability']:.2f} | {c['verdict']} | "
                f"{c['fit_seconds']:.0f} + {c['confidence_seconds']:.0f} |"
            )
        gaps = [conf[r["game"]]["gap"] for r in rows]
        within = sum(g <= WITHIN for g in gaps)
        parts.append(
            f"**{title}** (mean gap {np.mean(gaps):+.3f}, largest {max(gaps):+.3f}; within 3 points "
            f"of the ceiling: {within} of {len(gaps)})\n\n{head}\n" + "\n".join(lines) + "\n"
        )
    return "\n".join(parts)


def spread(row: dict) -> str:
    """The accuracy's range over a game's seeds ("low-high, "), or nothing for one seed."""
    return f"{row['low']:.3f}-{row['high']:.3f}, " if row["seeds"] > 1 else ""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("evaluated", type=Path, help="benchmarks.zoo.evaluate --out")
    ap.add_argument("confidence", type=Path, help="benchmarks.zoo.confidence --out")
    args = ap.parse_args()
    evaluated = json.loads(args.evaluated.read_text())  # evaluate writes a list of rows
    print(table(evaluated, json.loads(args.confidence.read_text())["rows"]))


if __name__ == "__main__":
    main()
