"""Do the agents keep their styles? PCPG against No Clustering, and each style's agent rolled
out in the real game and classified back, on every zoo game that has a Gymnasium env.

    uv run python -m benchmarks.zoo.agents [GAME ...] [--ci] [--rollouts 20]

Each game's full-size log (``--ci``: the small counts) goes through `pcpg run` as a user would
run it (`domain: trajectories`, k = its styles, the default clusterer, seed 0, p = 1, no
tracking), with the game's Gymnasium env for rollouts. Printed per game: the clustering's
accuracy, PCPG's and No Clustering's held-out accuracy at p = 1 (PCPG >= NC is the bar), and
``rollout/style_kept``: the share of each cluster's agent's episodes that the run's clustering
model (what `pcpg classify` uses) puts back in that agent's own cluster (>= 0.8 is the bar).

Only games whose recorded state is the env's own observation can be rolled out here; the others
(MiniGrid adds the agent's position, highway-env needs a nested config, MuJoCo's forces are
discretised, the board and card games have no Gymnasium env) run without rollouts, for PCPG
against No Clustering, and say why.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import tempfile
import time
from pathlib import Path

import yaml

from benchmarks.zoo.build import build
from benchmarks.zoo.common import game_names, load_game

#: when a rollout episode succeeds, per game (the Gymnasium env's own ending)
SUCCESS = {"cartpole": "reached_time_limit"}
#: the env's kwargs where a game's are not plain values (highway-env's nested config)
PLAIN = (str, int, float, bool, type(None))


def rollable(name: str) -> str | None:
    """Why a game cannot be rolled out here (None: it can)."""
    game = load_game(name)
    if game.gymnasium_env is None:
        return "its state is not the env's observation"
    if not all(isinstance(v, PLAIN) for v in game.gymnasium_kwargs.values()):
        return "its env needs a nested config"
    return None


def run_game(name: str, out: Path, ci: bool, rollouts: int, sets: tuple[str, ...] = ()) -> dict:
    """One game through `pcpg run`: with rollouts where the game has a usable env, else the
    held-out accuracies only (PCPG against No Clustering needs no env)."""
    game = load_game(name)
    build(name, out, ci=ci)
    cfg = yaml.safe_load((out / name / "pcpg.yaml").read_text())
    cfg["trajectories"]["path"] = str(out / name / "labelled")
    if rollable(name) is None:
        cfg["trajectories"].update(
            # ALE's ids exist once ale_py is imported: Gymnasium's "module:id" form imports it
            gymnasium_env=("ale_py:" if game.gymnasium_env.startswith("ALE/") else "")
            + game.gymnasium_env,
            gymnasium_kwargs=dict(game.gymnasium_kwargs),
            gymnasium_success=SUCCESS.get(name, "terminated"),
        )
    cfg.update(
        seeds=[0],
        ranking={"ps": [1.0]},
        evaluation={"rollouts_per_policy": rollouts, "corruption_levels": [], "figures": False},
    )
    path = out / name / "agents.yaml"
    path.write_text(yaml.safe_dump(cfg))
    t0 = time.perf_counter()
    done = subprocess.run(
        [
            "pcpg",
            "run",
            str(path),
            *sets,
            "--no-tracking",
            "-q",
            "--workdir",
            str(out / name / "runs"),
        ],
        capture_output=True,
        text=True,
        env={**os.environ, "RAY_ENABLE_UV_RUN_RUNTIME_ENV": "0"},
    )
    seconds = time.perf_counter() - t0
    if done.returncode != 0:
        return {"game": name, "error": done.stderr.strip().splitlines()[-1:]}
    summary = json.loads(
        (out / name / "runs" / cfg["name"] / "summary" / "metrics.json").read_text()
    )
    m = {key.split("/", 1)[1]: v for key, v in summary.items() if "/" in key}
    k = len(game.styles)
    return {
        "game": name,
        "held_out": game.held_out,
        "clustering": m.get("clustering/accuracy"),
        "stability": m.get("clustering/stability"),
        "pcpg": m.get("pcpg/accuracy/p1"),
        "nc": m.get("baseline/accuracy/p1"),
        # PCPG less NC on the same test steps, and its paired error (trajectories as the units)
        "lead": m.get("pcpg/lead_over_nc/p1"),
        "lead_se": m.get("pcpg/lead_over_nc_se/p1"),
        "kept": m.get("rollout/style_kept/p1"),
        "kept_each": [m.get(f"rollout/style_kept/k{c}/p1") for c in range(k)],
        "not_rolled_out": rollable(name),
        "seconds": seconds,
    }


def fmt(x) -> str:
    return "–" if x is None else f"{x:.3f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("games", nargs="*", help="zoo games (default: every game with an env)")
    ap.add_argument("--ci", action="store_true", help="the small counts")
    ap.add_argument("--rollouts", type=int, default=20, help="episodes per agent")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    ap.add_argument("--rollable-only", action="store_true", help="only games with a usable env")
    ap.add_argument("--set", nargs="*", default=[], help="config overrides, as `pcpg run` takes")
    args = ap.parse_args()
    names = args.games or game_names()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            if args.rollable_only and rollable(name) is not None:
                continue
            row = run_game(name, Path(tmp), args.ci, args.rollouts, tuple(args.set))
            rows.append(row)
            print(json.dumps(row), flush=True)
    print()
    print(
        "| game | held out | clustering acc | PCPG p=1 | NC p=1 | PCPG >= NC | style kept (mean; per agent) | s |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "error" in r:
            print(f"| {r['game']} | | failed: {r['error']} | | | | | |")
            continue
        better = None if r["pcpg"] is None or r["nc"] is None else r["pcpg"] >= r["nc"]
        each = ", ".join(fmt(x) for x in r["kept_each"])
        kept = (
            f"{fmt(r['kept'])} ({each})"
            if r["not_rolled_out"] is None
            else (f"not rolled out: {r['not_rolled_out']}")
        )
        print(
            f"| {r['game']} | {'yes' if r['held_out'] else ''} | {fmt(r['clustering'])} | "
            f"{fmt(r['pcpg'])} | {fmt(r['nc'])} | {'yes' if better else 'no'} | "
            f"{kept} | {r['seconds']:.0f} |"
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
