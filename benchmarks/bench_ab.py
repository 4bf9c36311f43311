"""Side by side: the same `pcpg run` in another checkout (say the commit before a redesign) and in
this one, alternating A, B, A, B on the same warm machine; prints each wall time, the medians,
the ratio B / A, and whether the two runs' metrics are equal (timings excluded).

    git worktree add /tmp/base a21b076 && (cd /tmp/base && uv sync --locked)
    uv run python benchmarks/bench_ab.py /tmp/base experiments/quick.yaml --repeats 3

Each run is a fresh process (`python -m pcpg_dist.cli run`, as a user starts it) with a fresh
working folder and MLflow store, so Ray start, imports and tracking are all in the figure.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def one_run(tree: Path, config: Path, tmp: Path) -> tuple[float, dict[str, float]]:
    python = tree / ".venv" / "bin" / "python"
    work = tmp / "runs"
    cmd = [str(python), "-m", "pcpg_dist.cli", "-q", "run", str(config), "--workdir", str(work)]
    cmd += ["--tracking-uri", f"sqlite:///{tmp}/mlflow.db"]
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=tree, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    metrics_file = next(work.glob("*/summary/metrics.json"))
    metrics = json.loads(metrics_file.read_text())
    return wall, {k: v for k, v in metrics.items() if "seconds" not in k}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("base", type=Path, help="the other checkout (with its .venv)")
    ap.add_argument("config", type=Path, help="experiment YAML (relative to this checkout)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    config = (ROOT / args.config).resolve() if not args.config.is_absolute() else args.config
    walls: dict[str, list[float]] = {"A": [], "B": []}
    results: dict[str, dict] = {}
    for i in range(args.repeats):
        for label, tree in (("A", args.base.resolve()), ("B", ROOT)):
            with tempfile.TemporaryDirectory() as tmp:
                wall, metrics = one_run(tree, config, Path(tmp))
            walls[label].append(wall)
            results[label] = metrics
            print(f"run {i + 1} {label}: {wall:6.1f} s", flush=True)
    a, b = statistics.median(walls["A"]), statistics.median(walls["B"])
    same = results["A"] == results["B"]
    print(f"{config.name}: A {args.base} median {a:.1f} s, B {ROOT} median {b:.1f} s")
    print(f"  B / A = {b / a:.3f}; metrics equal: {same} ({len(results['B'])} metrics)")
    if not same:
        diff = [
            k
            for k in results["A"].keys() | results["B"].keys()
            if results["A"].get(k) != results["B"].get(k)
        ]
        print(f"  differing: {sorted(diff)[:10]}", file=sys.stderr)


if __name__ == "__main__":
    main()
