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

from benchmarks.zoo.evaluate import METHODS


def table(evaluated: list[dict], confidence: list[dict]) -> str:
    conf = {r["game"]: r for r in confidence}
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
            lines.append(
                f"| {r['game']} | {', '.join(r['kinds'])} | {r['trajectories']} | "
                f"{ceiling:.3f} | {accs} | {c['accuracy']:.3f} ({ran}) | {c['gap']:+.3f} | "
                f"{c['stability']:.2f} | {c['verdict']} | "
                f"{c['fit_seconds']:.0f} + {c['confidence_seconds']:.0f} |"
            )
        gaps = [conf[r["game"]]["gap"] for r in rows]
        within = sum(g <= 0.03 + 1e-9 for g in gaps)
        parts.append(
            f"**{title}** (mean gap {np.mean(gaps):+.3f}, largest {max(gaps):+.3f}; within 3 points "
            f"of the ceiling: {within} of {len(gaps)})\n\n{head}\n" + "\n".join(lines) + "\n"
        )
    return "\n".join(parts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("evaluated", type=Path, help="benchmarks.zoo.evaluate --out")
    ap.add_argument("confidence", type=Path, help="benchmarks.zoo.confidence --out")
    args = ap.parse_args()
    evaluated = json.loads(args.evaluated.read_text())  # evaluate writes a list of rows
    print(table(evaluated, json.loads(args.confidence.read_text())["rows"]))


if __name__ == "__main__":
    main()
