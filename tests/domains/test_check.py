"""check_domain: a domain run through every rule pcpg holds it to, one line on the first broken one."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from bc_toy import make_dataset, rollout

from pcpg_dist.common.errors import DomainError
from pcpg_dist.config import parse_config
from pcpg_dist.domains.base import Domain, DomainHooks, Unit
from pcpg_dist.domains.check import check_domain

#: a built-in domain's config small enough to generate twice in a test
SMALL = {
    "name": "check",
    "domain": "minidungeons",
    "seed": 0,
    "seeds": [0],
    "minidungeons": {
        "train_levels": ["test"],
        "test_levels": ["holmgard_1"],
        "runs_per_level": 1,
        "max_steps": 40,
    },
    "evaluation": {"max_steps": 40},
}


@pytest.fixture(scope="module")
def cfg():
    return parse_config(SMALL)


class ToyDomain(Domain):
    """A plugin-like domain that keeps every rule: the toy grid of tests/bc_toy.py."""

    name = "toy"

    def generate(self, cfg, show_progress: bool = True):
        return {"grid5": make_dataset(8, seed=cfg.seed)}

    def hooks(self, cfg, unit: str) -> DomainHooks:
        return DomainHooks(rollout=rollout)


_draws = itertools.count()


class ReturnsAList(ToyDomain):
    def generate(self, cfg, show_progress: bool = True):
        return [make_dataset(8)]


class DrawsFromGlobalState(ToyDomain):
    def generate(self, cfg, show_progress: bool = True):
        return {"grid5": make_dataset(8, seed=next(_draws))}


class HoldsOutTooMuch(ToyDomain):
    def units(self, cfg, datasets):
        ds = datasets["grid5"]
        return [Unit("grid5", ds, np.array([0, ds.n_trajectories]))]


class RollsOutTooFew(ToyDomain):
    def hooks(self, cfg, unit: str) -> DomainHooks:
        return DomainHooks(rollout=lambda policy, n, rng: rollout(policy, n - 1, rng))


class KeysOnAnObject(ToyDomain):
    def data_key(self, cfg):
        return [self.name, object()]


class ScoresOnePerRow(ToyDomain):
    def score(self, cfg):
        return lambda ds: np.zeros(len(ds.actions))


def test_a_built_in_domain_passes(cfg):
    check_domain(cfg.domain_object, cfg)


def test_a_domain_that_keeps_the_rules_passes(cfg):
    check_domain(ToyDomain(), cfg)


@pytest.mark.parametrize(
    ("domain", "says"),
    [
        (ReturnsAList(), "domain 'toy': generate returned a list; it must return a non-empty dict"),
        (DrawsFromGlobalState(), "domain 'toy': generate returned other data for 'grid5'"),
        (HoldsOutTooMuch(), "domain 'toy': units returned unit 'grid5' with test_idx 16, outside"),
        (RollsOutTooFew(), "domain 'toy': the rollout hook returned a Dataset of 1 episode(s)"),
        (KeysOnAnObject(), "domain 'toy': data_key returned a part that is not JSON-able"),
        (ScoresOnePerRow(), "domain 'toy': its score function returned shape (158,) for grid5"),
    ],
)
def test_the_first_broken_rule_is_one_line(cfg, domain, says):
    with pytest.raises(DomainError) as err:
        check_domain(domain, cfg)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(says), message


def test_an_object_that_is_no_domain_is_refused(cfg):
    with pytest.raises(DomainError, match="object is not a pcpg Domain"):
        check_domain(object(), cfg)  # type: ignore[arg-type]
