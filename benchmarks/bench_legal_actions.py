"""Many actions, few legal: the policies' dense softmax against scoring the legal pairs only
(:mod:`pcpg_dist.stages.clustering.legal_actions`), side by side in one run, on chess's shapes
(4,672 move ids, 30 legal a row, 774 state features).

    uv run python -m benchmarks.bench_legal_actions [--threads 2] [--repeats 5]

For each network, milliseconds per forward + backward step of its fit, dense / legal pairs, and
the ratio: policy_mix's ``PolicyMixture`` (k = 4 heads, 32 hidden units) on 14,000 rows (the
whole blind chess log), and the latent start's ``LatentPolicies`` (eight fits side by side, 64
units, a 4-d latent) on 1,024 rows (one step of the consensus). The two paths give the same
values (``tests/stages/test_legal_actions.py``).

Then the latent start's whole Adam steps (forward, backward, Adam; eight fits of 1,024 rows) on
a log whose legal moves come from 1,745 of the 4,672 ids (as chess's 80-game log), the fits
over every id against the ids legal somewhere in the log (``legal_actions.on_legal_ids``).
"""

from __future__ import annotations

import argparse
import time

import torch

from pcpg_dist.common.devices import set_threads
from pcpg_dist.config.clustering import ClusterConfig
from pcpg_dist.stages import legal_share
from pcpg_dist.stages.clustering import latent_start, legal_actions
from pcpg_dist.stages.clustering.latent_start import LatentPolicies
from pcpg_dist.stages.clustering.policy_network import PolicyMixture

N_ACTIONS, LEGAL, STATE = 4672, 30, 774


def rows_of(rows: int, gen: torch.Generator, ids: int = N_ACTIONS):
    """(states, valid, actions): LEGAL random legal actions a row of the first ``ids``, the
    first of them taken."""
    order = torch.rand(rows, ids, generator=gen).argsort(1)[:, :LEGAL]
    valid = torch.zeros(rows, N_ACTIONS, dtype=torch.bool).scatter_(1, order, True)
    return torch.randn(rows, STATE, generator=gen), valid, order[:, 0]


def step_of(name: str, gen: torch.Generator):
    """A function running one forward + backward of ``name``'s fit."""
    if name == "policy_mix":
        s, valid, a = rows_of(14000, gen)
        net = PolicyMixture(STATE, 32, 4, N_ACTIONS)
        net.reset_parameters(gen)
        pairs = legal_actions.as_legal(valid, a)  # once, as policy_mix's fit does
        if not isinstance(pairs, legal_actions.Legal):
            raise SystemExit("chess's shapes should take the legal pairs")
        return lambda dense: net.step_log_probs(s, a, valid if dense else pairs).sum().backward()
    s, valid, a = rows_of(1024, gen)
    net = LatentPolicies(STATE, 400, 4, 64, N_ACTIONS, runs=8)
    net.reset_parameters(gen)
    traj, noise = torch.arange(1024) % 400, torch.randn(8, 1024, 4, generator=gen)
    # the latent fit draws new rows every step: their pairs are found every step (in step_nll)
    return lambda dense: net.step_nll(s, a, valid, traj, noise).sum().backward()


def timed(step, dense: bool, repeats: int) -> float:
    """Milliseconds a step, the dense softmax (every mask kept as it is) or the legal pairs."""
    saved = legal_share.SPARSE_MIN_ACTIONS
    if dense:
        legal_share.SPARSE_MIN_ACTIONS = 10**9
    try:
        step(dense)  # the kernels compiled, the allocator warm
        t0 = time.perf_counter()
        for _ in range(repeats):
            step(dense)
        return (time.perf_counter() - t0) / repeats * 1e3
    finally:
        legal_share.SPARSE_MIN_ACTIONS = saved


#: ids legal somewhere in chess's 80-game log
CHESS_IDS = 1745


def latent_seconds(every_id: bool, steps: int) -> float:
    """Seconds of ``steps`` Adam steps of the latent start's eight fits (1,024 rows a step)."""
    gen = torch.Generator().manual_seed(0)
    s, valid, a = rows_of(14000, gen, CHESS_IDS)
    inputs = (s, a, valid, torch.arange(14000) % 400)
    cfg = ClusterConfig(method="policy_mix", k=4)
    plan, same = latent_start.latent_plan, latent_start.on_legal_ids
    latent_start.latent_plan = lambda cfg, rows: (8, steps, 1024)
    if every_id:
        latent_start.on_legal_ids = lambda a, valid, n: (a, valid, n)
    try:
        latent_start.fit_latents(inputs, 400, cfg, N_ACTIONS, gen)  # compiled, warm
        t0 = time.perf_counter()
        latent_start.latent_start(inputs, 400, cfg, N_ACTIONS, seed=0)
        return time.perf_counter() - t0
    finally:
        latent_start.latent_plan, latent_start.on_legal_ids = plan, same


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    set_threads(args.threads)
    print(f"{'network':<22} {'dense ms':>9} {'legal pairs ms':>15} {'dense / pairs':>14}")
    for name in ("policy_mix", "latent_start"):
        step = step_of(name, torch.Generator().manual_seed(0))
        dense, pairs = timed(step, True, args.repeats), timed(step, False, args.repeats)
        print(f"{name:<22} {dense:9.1f} {pairs:15.1f} {dense / pairs:13.2f}x", flush=True)
    steps = 20
    every, legal = latent_seconds(True, steps), latent_seconds(False, steps)
    print(f"\nlatent start, {steps} Adam steps (eight fits), legal moves among {CHESS_IDS} ids:")
    print(f"{'all 4,672 ids s':>16} {'legal ids s':>12} {'ratio':>7}")
    print(f"{every:16.2f} {legal:12.2f} {every / legal:6.2f}x", flush=True)


if __name__ == "__main__":
    main()
