"""The background warm-up compiles every numba kernel a run may need, so that a fresh install's
first run pays no JIT cost (issue 35, item 5)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import torch

from pcpg_dist.cli import warm_kernels
from pcpg_dist.stages.clustering.legal_actions import Legal, as_legal
from pcpg_dist.stages.clustering.policy_network import policy_inputs
from pcpg_dist.stages.clustering.states import checked_sequences, fit_normaliser


def test_the_many_action_walks_take_the_legal_pairs():
    """The warm-up's many-action log is one the clusterers score at the legal pairs only (were
    the rule to change, the pairs' kernels would silently go unwarmed)."""
    ds = warm_kernels.many_action_walks(np.random.default_rng(0))
    states, _ = checked_sequences(ds)
    s, a, valid, _ = policy_inputs(ds, states, *fit_normaliser(states))
    assert isinstance(as_legal(valid, a), Legal)
    # and its actions are legal where taken (a log as pcpg reads one)
    assert bool(valid[torch.arange(len(a)), a].all())


@pytest.mark.slow
def test_the_warm_up_caches_every_kernel_it_names(tmp_path):
    """An empty numba cache reads as not cached; after the warm-up, every kernel of KERNELS has
    its cache index there (greedy_mix's, BC's, and the legal pairs')."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    check = [sys.executable, "-c", "from pcpg_dist.cli.warm_kernels import cached; print(cached())"]
    before = subprocess.run(check, env=env, capture_output=True, text=True, check=True)
    assert before.stdout.strip() == "False"
    warm = [sys.executable, "-m", "pcpg_dist.cli.warm_kernels"]
    subprocess.run(warm, env=env, capture_output=True, text=True, check=True, timeout=600)
    after = subprocess.run(check, env=env, capture_output=True, text=True, check=True)
    assert after.stdout.strip() == "True"
    names = {p.name for p in tmp_path.rglob("*.nbi")}
    for _, prefix in warm_kernels.KERNELS:
        assert any(name.startswith(prefix) for name in names), (prefix, sorted(names))
