"""bc.init auto's fine-tune check, side by side: PCPG against No Clustering at p = 1 on zoo games
with the check (the default, ``bc.finetune_check: 0.2``) and without it (0: every doubted
unit's per-cluster agents keep their 100-step fine-tune from the No Clustering agent).

    uv run python -m benchmarks.zoo.finetune_check [GAME ...] [--ci] [--json FILE]

Each game runs through `pcpg run` as :mod:`benchmarks.zoo.agents` runs it (seed 0, p = 1, one
rollout an agent where the game has an env: rollouts do not decide PCPG >= NC), twice in one
work folder, so both runs share one clustering and one No Clustering agent and differ only in
the per-cluster agents. The check
matters only where the unit's verdict doubts its styles; the default games are those whose
verdict did in the zoo's table (docs/zoo.md).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from benchmarks.zoo.agents import fmt, run_game

#: the zoo games whose verdict reads "weak evidence" or "no evidence" (docs/zoo.md's one table)
DOUBTED = (
    "tictactoe",
    "leduc_poker",
    "minigrid_empty",
    "highway",
    "minigrid_fourrooms",
    "connect_four",
    "minigrid_doorkey",
    "mujoco_reacher",
    "roundabout",
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("games", nargs="*", help="zoo games (default: those whose verdict doubts)")
    ap.add_argument("--ci", action="store_true", help="the small counts")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.games or DOUBTED:
            off = run_game(name, Path(tmp), args.ci, 1, ("bc.finetune_check=0",))
            on = run_game(name, Path(tmp), args.ci, 1, ())
            row = {"game": name, "unchecked": off, "checked": on}
            rows.append(row)
            print(json.dumps(row), flush=True)
    print()
    print(
        "| game | held out | clustering acc | stability | NC p=1 | PCPG unchecked | PCPG checked |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        off, on = r["unchecked"], r["checked"]
        if "error" in off or "error" in on:
            print(f"| {r['game']} | failed: {off.get('error') or on.get('error')} | | | | | |")
            continue
        print(
            f"| {r['game']} | {'yes' if on['held_out'] else ''} | {fmt(on['clustering'])} | "
            f"{fmt(on['stability'])} | {fmt(on['nc'])} | {fmt(off['pcpg'])} | {fmt(on['pcpg'])} |"
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
