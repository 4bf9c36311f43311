"""policy_mix's latent start, swept on design games (docs/zoo.md, "A style latent as
policy_mix's start"). Held-out games are refused.

    uv run python -m benchmarks.zoo.build --out zoo_data
    uv run python -m benchmarks.zoo.latent_exp zoo_data highway leduc_poker --dims 2 4 8 --em

For each setting (``--runs``: fits side by side, joined by their consensus): the accuracy of
the start alone (``pcpg_dist.stages.clustering.latent_start``) and, with ``--em``, of
policy_mix's EM started from it (the default), beside policy_mix started from counters
(``policy_start: counters``, the earlier default).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch


def run_game(ds, k: int, truth: np.ndarray, args) -> list[str]:
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.stages.clustering import clustering_metrics
    from pcpg_dist.stages.clustering.latent_start import latent_start
    from pcpg_dist.stages.clustering.policy_mix import _fit_policy_mix, _policy_view
    from pcpg_dist.stages.clustering.states import checked_sequences

    states, offsets = checked_sequences(ds)
    n, out = len(offsets) - 1, []

    def em(cfg) -> float:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(0)
            labels, *_ = _fit_policy_mix(ds, states, offsets, cfg, 0, {})
        return clustering_metrics(truth, labels)["accuracy"]

    base = ClusterConfig(method="policy_mix", k=k, policy_time=args.time_step)
    inputs = _policy_view(ds, states, base)[3]  # the settings swept do not change them
    if args.em:
        t0 = time.perf_counter()
        acc = em(base.model_copy(update={"policy_start": "counters"}))
        out.append(f"counters -> em {acc:.3f} ({time.perf_counter() - t0:.0f} s)")
    for d, beta, steps, seed, runs in (
        (d, b, st, s, r) for d in args.dims for b in args.betas for st in args.steps
        for s in args.seeds for r in args.runs
    ):  # fmt: skip
        cfg = base.model_copy(
            update={
                "latent_dims": d,
                "latent_beta": beta,
                "latent_steps": steps,
                "latent_runs": runs,
            }
        )
        t0 = time.perf_counter()
        alone = clustering_metrics(truth, latent_start(inputs, n, cfg, ds.n_actions, seed))
        line = f"d={d} beta={beta} steps={steps} seed={seed} runs={runs} latent {alone['accuracy']:.3f}"
        t1 = time.perf_counter()
        if args.em and seed == 0:
            line += f" -> em {em(cfg):.3f}"
        out.append(line + f" (start {t1 - t0:.1f} s, all {time.perf_counter() - t0:.0f} s)")
    return out


def main() -> None:
    from benchmarks.zoo.check import for_design_games
    from pcpg_dist.common.devices import set_threads

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path, help="benchmarks.zoo.build --out")
    ap.add_argument("games", nargs="+")
    ap.add_argument("--dims", type=int, nargs="+", default=[4])
    ap.add_argument("--betas", type=float, nargs="+", default=[0.1])
    ap.add_argument("--steps", type=int, nargs="+", default=[1000])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--runs", type=int, nargs="+", default=[1], help="latent fits joined")
    ap.add_argument("--rows", type=int, default=None, help="rows per latent Adam step")
    ap.add_argument("--hidden", type=int, default=None, help="hidden units of the latent policy")
    ap.add_argument("--time-step", action="store_true", help="policies see log(1 + t)")
    ap.add_argument("--em", action="store_true", help="also policy_mix's EM from each start")
    args = ap.parse_args()
    set_threads(1)
    from pcpg_dist.stages.clustering import latent_start

    if args.rows:
        latent_start.LATENT_ROWS = args.rows
    if args.hidden:
        latent_start.LATENT_HIDDEN = args.hidden
    for_design_games(args.root, args.games, ap.error, lambda *unit: run_game(*unit, args))


if __name__ == "__main__":
    main()
