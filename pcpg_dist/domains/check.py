"""``check_domain``: run a domain through every rule pcpg holds it to, before a real run does.

Like gymnasium's ``check_env``: a plugin author (or a test) hands over a domain object and a small
config, and learns in one line which rule the domain breaks, instead of meeting it minutes into
``pcpg run``. The rules are the ones :mod:`pcpg_dist.domains.contract` enforces where pcpg calls
the domain (settings, data key, data, manifest, units, skill score, hooks); on top of them the
data must come out the same twice (the cache and every number rely on it) and a rollout hook must
play the episodes asked for. The domain need not be registered: it is checked as given.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

import numpy as np

from pcpg_dist.common.errors import DomainError, PcpgError, first_line
from pcpg_dist.domains import contract, sources
from pcpg_dist.domains.base import Domain, Unit, random_policy
from pcpg_dist.domains.defaults import in_process

if TYPE_CHECKING:
    from pcpg_dist.config import ExperimentConfig
    from pcpg_dist.dataset import Dataset

ROLLOUT_EPISODES = 2  # episodes a rollout hook is asked for: enough to see it count them


def check_domain(domain: Domain, cfg: ExperimentConfig) -> None:
    """Raise :class:`DomainError` (one line) on the first rule ``domain`` breaks on ``cfg``.

    ``cfg`` should be small: the data is generated twice, in this process (no Ray). Checked in
    order: the object is a named :class:`Domain`; its settings and ``check_config``; ``data_key``
    (a list of JSON-able parts); ``data_source``; ``generate`` (a dict of environment -> Dataset, the same twice);
    ``manifest``; ``units`` (with their skill score and hooks); one rollout per unit's hook."""
    if not isinstance(domain, Domain):
        raise DomainError(
            f"{type(domain).__name__} is not a pcpg Domain; subclass pcpg_dist.domains.base.Domain"
        )
    if not isinstance(domain.name, str) or not domain.name:
        raise DomainError(f"{type(domain).__name__}: its name must be a non-empty str")
    with _rule(domain, "settings"):
        domain.settings(cfg)
    with _rule(domain, "check_config"), contract.calling(domain, "check_config"):
        domain.check_config(cfg)
    with _rule(domain, "data_key"):
        _check_data_key(domain, cfg)
    with _rule(domain, "data_source"):
        sources.data_source(cfg, domain)
    with _rule(domain, "generate"):
        datasets = _check_generate(domain, cfg)
    with _rule(domain, "manifest"):
        contract.manifest(cfg, datasets, domain)
    with _rule(domain, "units"):
        units = contract.units(cfg, datasets, domain)
    with _rule(domain, "hooks"):
        for unit in units:
            _check_rollout(domain, cfg, unit)


@contextmanager
def _rule(domain: Domain, method: str) -> Iterator[None]:
    """One rule's check: pcpg's own error of another kind (a ConfigError from the settings, a
    DataError from building an invalid Dataset) becomes a DomainError naming the method."""
    try:
        yield
    except DomainError:
        raise
    except PcpgError as e:
        said = first_line(e)
        if said.startswith(f"domain {domain.name!r}: "):  # it names the domain already
            raise DomainError(said) from e
        raise DomainError(f"domain {domain.name!r}: {method}: {said}") from e


def _check_data_key(domain: Domain, cfg: ExperimentConfig) -> None:
    parts = contract.data_key(cfg, domain)
    try:
        json.dumps(parts, default=_model_dump)
    except (TypeError, ValueError) as e:
        raise DomainError(
            f"domain {domain.name!r}: data_key returned a part that is not JSON-able "
            f"({first_line(e)}); it must return a list of JSON-able parts"
        ) from None


def _model_dump(value: Any) -> Any:
    """A pydantic model (a settings section) as its JSON-able dump; anything else is refused."""
    dump: Callable[..., Any] | None = getattr(value, "model_dump", None)
    if dump is None:
        raise TypeError(f"{type(value).__name__} is not JSON serializable")
    return dump(mode="json")


def _check_generate(domain: Domain, cfg: ExperimentConfig) -> dict[str, Dataset]:
    """The data, generated twice in this process; both times the same."""
    from pcpg_dist.dataset import content_digest

    first = contract.generate(cfg, False, in_process, domain)
    again = contract.generate(cfg, False, in_process, domain)
    for name, ds in first.items():
        other = again.get(name)
        if other is None or content_digest(other) != content_digest(ds) or not _same(ds, other):
            raise DomainError(
                f"domain {domain.name!r}: generate returned other data for {name!r} the second "
                f"time; draw every random number from a generator seeded by cfg.seed"
            )
    return first


def _same(a: Dataset, b: Dataset) -> bool:
    """What the digest leaves out: styles, rewards, success."""
    return all(
        np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True)
        for f in ("styles", "success", "rewards")
    )


def _check_rollout(domain: Domain, cfg: ExperimentConfig, unit: Unit) -> None:
    """A unit's rollout hook, asked for a few random-policy episodes (the contract checks the
    count and that a Dataset comes back)."""
    hooks = contract.hooks(cfg, unit.name, domain)
    if hooks is None or hooks.rollout is None:
        return
    hooks.rollout(random_policy, ROLLOUT_EPISODES, np.random.default_rng(0))
