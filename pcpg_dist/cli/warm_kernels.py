"""Compile the numba kernels ahead of a fresh install's first run, in the background.

Why: numba compiles a kernel the first time it runs and caches the machine code beside its
source (``__pycache__/*.nbi``, or ``NUMBA_CACHE_DIR``). On a fresh install the first `pcpg run`
paid that in its Ray workers, in the hot path: ~12 s on this project's 2-core machine (the BC
kernel 6 s, greedy_mix's 4 s; the BC kernel alone took 25 s before it dropped ``parallel=True``).
The commands that start a local Ray (`pcpg run`, `sweep`, `cluster`, `tune`, `generate`) start
this module in a background process when a kernel's cache index is missing, so the compiling
overlaps Ray's start and the first stage; a worker that needs a kernel before it is cached
compiles it itself, as before. A domain's own kernels (a built-in game's data generation, ~2 s)
compile where they run.

It runs the public entry points on a tiny problem built as a log is (never hand-typed dummies:
the argument types, and so the compiled specialisations, are exactly those of a run): greedy_mix
on a few random walks over one-hot states, one BC step on them, and policy_mix on walks of many
action ids with a few legal a step (the legal pairs' kernels, :mod:`..stages.clustering.
legal_actions`, which a board game's log of thousands of move ids runs on).

    python -m pcpg_dist.cli.warm_kernels
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1]
#: (module folder under the package, the cache index's name prefix) of each kernel warmed here
KERNELS = (
    ("stages/clustering", "greedy_likelihood._ascend-"),
    ("stages/clustering", "legal_actions._forward-"),
    ("stages/clustering", "legal_actions._grad_x-"),
    ("stages/clustering", "legal_actions._grad_w-"),
    ("stages/bc", "kernel.train_kernel-"),
)


def cached() -> bool:
    """Whether every kernel has a cache index where numba looks first (``NUMBA_CACHE_DIR``, else
    the source's ``__pycache__``); a stale index (changed source) still counts: numba recompiles
    that one kernel at its first use."""
    root = os.environ.get("NUMBA_CACHE_DIR")
    for folder, prefix in KERNELS:
        place = Path(root) if root else PACKAGE / folder / "__pycache__"
        pattern = f"**/{prefix}*.nbi" if root else f"{prefix}*.nbi"
        if not place.is_dir() or next(place.glob(pattern), None) is None:
            return False
    return True


def start_in_background() -> None:
    """Start the warm-up in a detached process unless every kernel is cached; never fails a run
    (a warm-up that cannot start leaves the kernels to compile where they are used)."""
    if os.environ.get("PCPG_NO_WARMUP") or cached():
        return
    with contextlib.suppress(OSError):
        subprocess.Popen(
            [sys.executable, "-m", "pcpg_dist.cli.warm_kernels"],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )


def warm() -> None:
    """Run every kernel once on a tiny problem (compiling and caching it)."""
    import numpy as np
    import torch

    torch.set_num_threads(1)
    from pcpg_dist.config.clustering import ClusterConfig
    from pcpg_dist.config.stages import BCConfig
    from pcpg_dist.dataset import Dataset
    from pcpg_dist.stages.bc import train_cells
    from pcpg_dist.stages.clustering.step import cluster_once as cluster
    from pcpg_dist.stages.ranking import RankConfig, plan_cells

    rng = np.random.default_rng(0)
    walks = []
    for i in range(8):
        cells = rng.integers(0, 5, 9)
        walks.append(
            {
                "states": np.eye(5, dtype=np.float32)[cells],
                "actions": (cells[1:] + i % 2) % 4,
                "valid": np.ones((9, 4), bool),
                "rewards": np.ones(8),
            }
        )
    styles = np.arange(8) % 2
    ds = Dataset.from_trajectories("warmup", "walks", 4, walks, styles, np.ones(8, bool))
    cluster(ds, ClusterConfig(method="greedy_mix", k=2, confidence_runs=0), 0)
    units = plan_cells(ds, ds.styles, np.arange(8), RankConfig(ps=(1.0,)), [0])
    train_cells(units[:1], BCConfig(epochs=1))
    many = many_action_walks(rng)
    cluster(many, ClusterConfig(method="policy_mix", k=2, confidence_runs=0, latent_steps=2), 0)


def many_action_walks(rng, n_actions: int = 64, legal: int = 4):
    """Eight walks over one-hot states whose steps allow ``legal`` of ``n_actions`` ids (the
    first taken): few enough that the clusterers score the legal pairs only
    (:mod:`pcpg_dist.stages.legal_share`)."""
    import numpy as np

    from pcpg_dist.dataset import Dataset

    walks = []
    for _ in range(8):
        allowed = np.stack([rng.permutation(n_actions)[:legal] for _ in range(9)])
        valid = np.zeros((9, n_actions), bool)
        np.put_along_axis(valid, allowed, True, axis=1)
        walks.append(
            {
                "states": np.eye(5, dtype=np.float32)[rng.integers(0, 5, 9)],
                "actions": allowed[:8, 0],
                "valid": valid,
                "rewards": np.ones(8),
            }
        )
    return Dataset.from_trajectories(
        "warmup", "moves", n_actions, walks, np.arange(8) % 2, np.ones(8, bool)
    )


if __name__ == "__main__":
    warm()
