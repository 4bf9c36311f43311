"""One continuous log of 1,600 trajectories end to end, BC as the session began beside now.

    uv run python -m benchmarks.bench_log_e2e [--trajectories 1600] [--variants start now fresh]
        [--start-checkout DIR]

Issue 35's speed target: a 1,600-trajectory continuous log runs end to end (cluster, train,
evaluate with rollouts in the real env, 2 seeds, p in {1, 0.5}, tracking on) in <= 3 min on 2
cores. The log is the zoo's MountainCar (2-d continuous states, 3 strategies in the game's
unequal proportions, up to 200 steps an episode); the config is what a user writes for it
(`domain: trajectories`, `k`, the env for rollouts, the seeds and thresholds).

Each variant runs `pcpg run` in a fresh process on the same log, one after another:
- ``start``: another checkout's `pcpg` (``--start-checkout``, with its own ``uv sync``ed
  ``.venv``: the code this work started from), its defaults;
- ``paper_bc``: this checkout with BC as the paper trains it: full batch for every cell, all
  2000 epochs (``bc.batch_size: null, bc.stop_tol: 0``);
- ``now``: the defaults (``batch_size: auto``: minibatches for cells of > 20,000 distinct rows;
  early stopping at 1e-4 nats a row over 100 steps; one unit's clustering on every CPU);
- ``fresh``: the defaults with an empty numba cache, as a fresh install's first run (the
  kernels then compile in the background while Ray starts).
Compiled kernels are cached beforehand (a warm-up run of each checkout) except for ``fresh``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
#: the summary metrics printed per variant: clustering accuracy, PCPG and No Clustering at each p
ACCURACY = r"(clustering/accuracy|pcpg/accuracy/p[\d.]+|baseline/accuracy/p[\d.]+)"
PAPER_BC = {"batch_size": None, "stop_tol": 0.0}


def build_log(n: int, out: Path) -> tuple[int, int]:
    """The MountainCar log with ``n`` trajectories in the zoo game's style proportions."""
    from benchmarks.zoo.common import episodes, step_table
    from benchmarks.zoo.mountaincar.generator import GAME

    total = sum(GAME.counts)
    counts = [round(n * c / total) for c in GAME.counts]
    counts[0] += n - sum(counts)
    played = episodes(dataclasses.replace(GAME, counts=tuple(counts)))
    table = step_table(played)
    table.to_parquet(out, index=False)
    return len(played), int((table["action"] >= 0).sum())


def config(log: Path, bc: dict) -> dict:
    return {
        "name": "log_e2e",
        "domain": "trajectories",
        "seeds": [0, 1],
        "trajectories": {
            "path": str(log),
            "score": "return",
            "n_actions": 3,
            "gymnasium_env": "MountainCar-v0",
        },
        "clustering": {"k": 3},
        "ranking": {"ps": [1.0, 0.5]},
        "bc": bc,
    }


def run_one(cfg_path: Path, workdir: Path, env: dict, pcpg: str = "pcpg") -> dict:
    """`pcpg run` in a fresh process; wall seconds and the stage times it printed."""
    t0 = time.perf_counter()
    done = subprocess.run(
        [pcpg, "run", str(cfg_path), "--workdir", str(workdir / "runs")],
        cwd=workdir,
        env=env,
        capture_output=True,
        text=True,
    )
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        sys.exit(f"pcpg run failed ({done.returncode}):\n{done.stderr[-3000:]}")
    stages = dict(
        (k, float(v))
        for k, v in re.findall(r"(\w+) ([\d.]+)s", done.stdout.split("time per stage:")[-1])
    )
    summary = json.loads((workdir / "runs" / "log_e2e" / "summary" / "metrics.json").read_text())
    return {"wall": wall, "stages": stages, "summary": summary}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trajectories", type=int, default=1600)
    ap.add_argument("--variants", nargs="+", default=["start", "paper_bc", "now", "fresh"])
    ap.add_argument("--start-checkout", type=Path, help="the checkout `start` runs")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        log = tmp / "mountaincar.parquet"
        t0 = time.perf_counter()
        n, steps = build_log(args.trajectories, log)
        print(
            f"log: {n} trajectories, {steps} steps ({steps / n:.0f} a trajectory), "
            f"built in {time.perf_counter() - t0:.0f} s",
            flush=True,
        )
        env = {**os.environ, "RAY_ENABLE_UV_RUN_RUNTIME_ENV": "0"}
        warm = tmp / "warm"
        warm.mkdir()
        small = tmp / "small.parquet"
        build_log(60, small)
        (warm / "pcpg.yaml").write_text(yaml.safe_dump(config(small, {})))
        start = str(args.start_checkout / ".venv" / "bin" / "pcpg") if args.start_checkout else None
        if "start" in args.variants and start is None:
            sys.exit("the start variant needs --start-checkout DIR")
        for exe in filter(None, ("pcpg", start if "start" in args.variants else None)):
            shutil.rmtree(warm / "runs", ignore_errors=True)
            run_one(warm / "pcpg.yaml", warm, env, exe)  # compiles and caches the kernels
        rows = []
        for variant in args.variants:
            folder = tmp / variant
            folder.mkdir()
            (folder / "pcpg.yaml").write_text(
                yaml.safe_dump(config(log, PAPER_BC if variant == "paper_bc" else {}))
            )
            run_env = dict(env)
            if variant == "fresh":
                run_env["NUMBA_CACHE_DIR"] = str(folder / "numba_cache")
            exe = start if variant == "start" else "pcpg"
            got = run_one(folder / "pcpg.yaml", folder, run_env, exe)
            rows.append((variant, got))
            stages = ", ".join(f"{k} {v:.0f}" for k, v in got["stages"].items())
            print(f"{variant:<7} {got['wall']:6.0f} s   ({stages})", flush=True)
        print()
        print("| variant | wall s | " + " | ".join(rows[0][1]["stages"]) + " |")
        print("|---|---|" + "---|" * len(rows[0][1]["stages"]))
        for variant, got in rows:
            cells = " | ".join(f"{v:.1f}" for v in got["stages"].values())
            print(f"| {variant} | {got['wall']:.1f} | {cells} |")
        base = dict(rows).get("start")
        for variant, got in rows:
            if base is not None and variant != "start":
                print(f"{variant} / start: {got['wall'] / base['wall']:.2f}")
        print()
        for variant, got in rows:
            acc = {k: v for k, v in got["summary"].items() if re.fullmatch(ACCURACY, k)}
            print(variant, " ".join(f"{k}={v:.3f}" for k, v in sorted(acc.items())))
        print("target: <= 180 s end to end on 2 cores")


if __name__ == "__main__":
    main()
