"""A domain's generate receives its fan-out; a plugin written without one keeps working."""

from __future__ import annotations

import numpy as np
from bc_toy import make_dataset

from pcpg_dist.config import parse_config
from pcpg_dist.domains import contract
from pcpg_dist.domains.base import Domain
from pcpg_dist.domains.defaults import in_process

SMALL = {
    "name": "fan-out",
    "domain": "minidungeons",
    "seed": 0,
    "seeds": [0],
    "minidungeons": {
        "train_levels": ["test"],
        "test_levels": ["holmgard_1"],
        "runs_per_level": 1,
        "max_steps": 40,
    },
}


def test_the_domain_fans_out_through_what_it_is_given():
    cfg = parse_config(SMALL)
    seen = []

    def recording(fn, calls, description, show_progress=True):
        seen.append((description, len(calls), show_progress))
        return in_process(fn, calls, description, show_progress)

    given = contract.generate(cfg, False, fan_out=recording)
    default = contract.generate(cfg, False)
    assert seen and all(d == "proxies (level, proxy)" and not shown for d, _, shown in seen)
    assert set(given) == set(default)
    for env, ds in given.items():
        np.testing.assert_array_equal(ds.states, default[env].states)
        np.testing.assert_array_equal(ds.actions, default[env].actions)


class WithoutProgress(Domain):
    name = "toy"

    def generate(self, cfg):
        return {"grid5": make_dataset(4)}


class WithProgressOnly(WithoutProgress):
    def generate(self, cfg, show_progress):
        assert show_progress is False
        return super().generate(cfg)


def test_a_plugin_generate_without_fan_out_is_called_as_written():
    cfg = parse_config(SMALL)
    for domain in (WithoutProgress(), WithProgressOnly()):
        (ds,) = contract.generate(cfg, False, domain=domain).values()
        assert ds.n_trajectories == 8
