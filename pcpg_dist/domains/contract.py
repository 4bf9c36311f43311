"""Every call into a domain, checked where pcpg receives the answer.

A domain may come from a third-party package (docs/writing-a-domain.md), so what its methods
return is input like a config or a file: it is checked here, at the boundary, and a value pcpg
cannot use stops the run with one :class:`~pcpg_dist.common.errors.DomainError` line naming the domain,
the method, what it returned and what is allowed, before the stage that would have tripped over
it (a bad ``generate`` or ``units`` before any clustering). An exception raised inside a
*plugin's* method becomes such a line too; one raised inside a built-in domain is a bug in
pcpg-dist and keeps its traceback. pcpg's own errors (a ``DataError`` from building an invalid
``Dataset``) pass unchanged: they already name what is wrong.

The runner, the pipeline, ``pcpg cluster`` and tuning call the domain only through this module.
"""

from __future__ import annotations

import contextlib
import inspect
import math
import numbers
import sys
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pcpg_dist.common.errors import DomainError, PcpgError, first_line
from pcpg_dist.domains.base import Domain, DomainHooks, FanOut, ScoreFn, Unit
from pcpg_dist.domains.defaults import in_process

if TYPE_CHECKING:
    from pcpg_dist.config import ExperimentConfig
    from pcpg_dist.dataset import Dataset


def is_plugin(domain: Domain) -> bool:
    """Whether ``domain`` comes from another package than pcpg-dist."""
    return type(domain).__module__.split(".")[0] != "pcpg_dist"


def _kind(value: Any) -> str:
    name = type(value).__name__
    return "None" if value is None else f"{'an' if name[0] in 'aeiouAEIOU' else 'a'} {name}"


def _fail(domain: Domain, method: str, problem: str) -> DomainError:
    return DomainError(f"domain {domain.name!r}: {method} {problem}")


@contextlib.contextmanager
def calling(domain: Domain, method: str) -> Iterator[None]:
    """Run a call into ``domain``: a plugin's exception becomes one line naming the domain, the
    method and the exception (an exception of a Ray task the plugin ran is unwrapped first)."""
    try:
        yield
    except PcpgError:
        raise
    except Exception as e:
        if not is_plugin(domain):
            raise
        ray = sys.modules.get("ray")
        while (
            ray is not None and isinstance(e, ray.exceptions.RayTaskError) and e.cause is not None
        ):
            e = e.cause
        if isinstance(e, PcpgError):
            raise e from None
        raise _fail(domain, method, f"raised {type(e).__name__}: {first_line(e)}") from e


def the_domain(cfg: ExperimentConfig, domain: Domain | None) -> Domain:
    """``domain`` where one is given (:func:`pcpg_dist.domains.check.check_domain` checks a domain
    not registered yet), else the config's."""
    return cfg.domain_object if domain is None else domain


# --------------------------------------------------------------------------- data
def data_key(cfg: ExperimentConfig, domain: Domain | None = None) -> list[Any]:
    """The domain's data key (the cache key of its data)."""
    return _key_parts(cfg, domain, "data_key")


def evaluation_key(cfg: ExperimentConfig, domain: Domain | None = None) -> list[Any]:
    """The domain's evaluation key (what besides the evaluation settings moves its numbers)."""
    return _key_parts(cfg, domain, "evaluation_key")


def _key_parts(cfg: ExperimentConfig, domain: Domain | None, method: str) -> list[Any]:
    """A domain's key method's parts, checked to be a list."""
    domain = the_domain(cfg, domain)
    with calling(domain, method):
        key = getattr(domain, method)(cfg)
    if not isinstance(key, list | tuple):
        raise _fail(
            domain, method, f"returned {_kind(key)}; it must return a list of JSON-able parts"
        )
    return list(key)


def generate(
    cfg: ExperimentConfig,
    show_progress: bool = True,
    fan_out: FanOut = in_process,
    domain: Domain | None = None,
) -> dict[str, Dataset]:
    """The domain's datasets: a non-empty dict of environment name -> Dataset, one per environment.

    ``fan_out`` runs the domain's batches of calls (the orchestration passes one that runs them
    as Ray tasks; by default they run here, one after another)."""
    from pcpg_dist.dataset import Dataset

    domain = the_domain(cfg, domain)
    with calling(domain, "generate"):
        datasets = _call_generate(domain, cfg, show_progress, fan_out)
    allowed = "it must return a non-empty dict of environment name -> Dataset"
    if not isinstance(datasets, dict):
        raise _fail(domain, "generate", f"returned {_kind(datasets)}; {allowed}")
    if not datasets:
        raise _fail(domain, "generate", f"returned an empty dict; {allowed}")
    envs: dict[str, str] = {}
    for name, ds in datasets.items():
        if not isinstance(name, str):
            raise _fail(
                domain, "generate", f"returned the key {name!r} ({type(name).__name__}); {allowed}"
            )
        if not isinstance(ds, Dataset):
            raise _fail(domain, "generate", f"returned {_kind(ds)} for {name!r}; {allowed}")
        if ds.env in envs:  # both would be written to the same file
            raise _fail(
                domain,
                "generate",
                f"returned two datasets of environment {ds.env!r} (keys "
                f"{envs[ds.env]!r} and {name!r}); each environment must come once",
            )
        envs[ds.env] = name
    return datasets


def _call_generate(
    domain: Domain, cfg: ExperimentConfig, show_progress: bool, fan_out: FanOut
) -> Any:
    """``domain.generate`` called the way its signature allows: ``fan_out`` by keyword where it
    names one, ``show_progress`` where it takes a second argument, so a plugin written as
    ``generate(self, cfg)`` or ``generate(self, cfg, show_progress)`` keeps working."""
    try:
        params = list(inspect.signature(domain.generate).parameters.values())
    except (TypeError, ValueError):  # a callable without a signature: call it as pcpg always has
        return domain.generate(cfg, show_progress)
    kwargs = {"fan_out": fan_out} if any(p.name == "fan_out" for p in params) else {}
    positional = [
        p
        for p in params
        if p.name != "fan_out"
        and p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD, p.VAR_POSITIONAL)
    ]
    if len(positional) >= 2 or any(p.kind is p.VAR_POSITIONAL for p in positional):
        return domain.generate(cfg, show_progress, **kwargs)
    return domain.generate(cfg, **kwargs)


def manifest(
    cfg: ExperimentConfig, datasets: dict[str, Dataset], domain: Domain | None = None
) -> dict[str, Any]:
    """The domain's extra provenance for the data's manifest.json."""
    domain = the_domain(cfg, domain)
    with calling(domain, "manifest"):
        extra = domain.manifest(cfg, datasets)
    if not isinstance(extra, dict):
        raise _fail(domain, "manifest", f"returned {_kind(extra)}; it must return a dict")
    return extra


def units(
    cfg: ExperimentConfig, datasets: dict[str, Dataset], domain: Domain | None = None
) -> list[Unit]:
    """The domain's evaluation units, checked (names, datasets, held-out indices in range); then
    the skill score and the hooks each unit will use are asked for once, so a broken one fails
    here, before any clustering, not after training."""
    from pcpg_dist.dataset import Dataset
    from pcpg_dist.domains.defaults import score_dataset

    domain = the_domain(cfg, domain)
    with calling(domain, "units"):
        found = domain.units(cfg, datasets)
    allowed = "it must return a non-empty list of Unit"
    if not isinstance(found, list | tuple):
        raise _fail(domain, "units", f"returned {_kind(found)}; {allowed}")
    if not found:
        raise _fail(domain, "units", f"returned an empty list; {allowed}")
    out: list[Unit] = []
    for i, u in enumerate(found):
        if not isinstance(u, Unit):
            raise _fail(domain, "units", f"returned {_kind(u)} at position {i}; {allowed}")
        if not isinstance(u.name, str) or not u.name or u.name in (v.name for v in out):
            raise _fail(
                domain,
                "units",
                f"returned a unit named {u.name!r} at position {i}; every unit "
                "needs its own non-empty name (a str)",
            )
        where = f"returned unit {u.name!r} with"
        if not isinstance(u.dataset, Dataset):
            raise _fail(
                domain, "units", f"{where} {_kind(u.dataset)} as its dataset; it must be a Dataset"
            )
        n = u.dataset.n_trajectories
        test = np.asarray(u.test_idx)
        if test.ndim != 1 or (test.size and test.dtype.kind not in "iu"):
            raise _fail(
                domain,
                "units",
                f"{where} test_idx of shape {test.shape} and dtype {test.dtype}; "
                "it must be a 1-D array of trajectory positions (integers)",
            )
        bad = test[(test < 0) | (test >= n)]
        if bad.size:
            raise _fail(
                domain,
                "units",
                f"{where} test_idx {int(bad[0])}, outside 0..{n - 1} (its dataset "
                f"holds {n} trajectories)",
            )
        if len(np.unique(test)) != test.size:
            raise _fail(
                domain, "units", f"{where} test_idx naming a trajectory twice; each position once"
            )
        if test.size >= n:
            raise _fail(
                domain,
                "units",
                f"{where} all {n} trajectories held out; at least one must be left for training",
            )
        ci = u.cluster_input
        if ci is not None and (not isinstance(ci, Dataset) or ci.n_trajectories != n):
            got = f"{ci.n_trajectories} trajectories" if isinstance(ci, Dataset) else _kind(ci)
            raise _fail(
                domain,
                "units",
                f"{where} {got} as its cluster_input; it must be a Dataset of the "
                f"same {n} trajectories as its dataset",
            )
        out.append(replace(u, test_idx=test.astype(np.int64)))
    fn = score(cfg, domain)
    for u in out:
        if fn is not None:
            score_dataset(u.dataset, cfg.ranking, fn)
        hooks(cfg, u.name, domain)
    return out


# --------------------------------------------------------------------------- stages
def score(cfg: ExperimentConfig, domain: Domain | None = None) -> ScoreFn | None:
    """The domain's skill score (None = the paper's Performance) as a function returning floats;
    their shape and finiteness are checked by :func:`pcpg_dist.domains.defaults.score_dataset`."""
    domain = the_domain(cfg, domain)
    with calling(domain, "score"):
        fn = domain.score(cfg)
    if fn is None:
        return None
    if not callable(fn):
        raise _fail(
            domain,
            "score",
            f"returned {_kind(fn)}; it must return None or a function "
            "Dataset -> one float per trajectory",
        )

    def checked(dataset: Dataset) -> np.ndarray:
        with calling(domain, "score's function"):
            values = fn(dataset)
        try:
            return np.asarray(values, dtype=np.float64)
        except (TypeError, ValueError):
            raise _fail(
                domain,
                "score's function",
                f"returned {_kind(values)} that does not convert to "
                "floats; it must return one float per trajectory",
            ) from None

    return checked


def hooks(cfg: ExperimentConfig, unit: str, domain: Domain | None = None) -> DomainHooks | None:
    """The domain's hooks for ``unit``, each wrapped so a plugin's exception is one line; a
    rollout must return a Dataset of the episodes asked for."""
    domain = the_domain(cfg, domain)
    with calling(domain, "hooks"):
        found = domain.hooks(cfg, unit)
    if found is None:
        return None
    if not isinstance(found, DomainHooks):
        raise _fail(
            domain,
            "hooks",
            f"returned {_kind(found)} for unit {unit!r}; it must return None or a DomainHooks",
        )
    fields = {}
    for name in ("rollout", "returns", "optimal_return", "draw"):
        fn = getattr(found, name)
        if fn is not None and not callable(fn):
            raise _fail(
                domain,
                "hooks",
                f"returned {_kind(fn)} as DomainHooks.{name} for unit {unit!r}; "
                "it must be None or a function",
            )
        fields[name] = None if fn is None else _wrapped(domain, f"the {name} hook", fn)
    if found.rollout is not None:
        fields["rollout"] = _checked_rollout(domain, fields["rollout"])
    return DomainHooks(**fields)


def _wrapped(domain: Domain, method: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    def call(*args: Any) -> Any:
        with calling(domain, method):
            return fn(*args)

    return call


def _checked_rollout(domain: Domain, rollout: Callable[..., Any]) -> Callable[..., Dataset]:
    from pcpg_dist.dataset import Dataset

    def checked(policy: Any, n_episodes: int, rng: np.random.Generator) -> Dataset:
        ds = rollout(policy, n_episodes, rng)
        got = (
            f"a Dataset of {ds.n_trajectories} episode(s)" if isinstance(ds, Dataset) else _kind(ds)
        )
        if not isinstance(ds, Dataset) or ds.n_trajectories != n_episodes:
            raise _fail(
                domain,
                "the rollout hook",
                f"returned {got}; it must return a Dataset of the {n_episodes} episodes asked for",
            )
        return ds

    return checked


def extras(
    cfg: ExperimentConfig, unit: Unit, labels: np.ndarray, trained: Any, out: Path
) -> dict[str, float]:
    """The domain's own metrics for ``unit``: a dict of metric name -> finite float."""
    domain = cfg.domain_object
    with calling(domain, "extras"):
        metrics = domain.extras(cfg, unit, labels, trained, out)
    allowed = "it must return a dict of metric name (str) -> finite float"
    if not isinstance(metrics, dict):
        raise _fail(
            domain, "extras", f"returned {_kind(metrics)} for unit {unit.name!r}; {allowed}"
        )
    checked: dict[str, float] = {}
    for name, value in metrics.items():
        if not isinstance(name, str) or not name:
            raise _fail(
                domain, "extras", f"returned the key {name!r} for unit {unit.name!r}; {allowed}"
            )
        number = isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)
        if not number or not math.isfinite(value):
            shown = (
                repr(value) if number or isinstance(value, str | bool | np.bool_) else _kind(value)
            )
            raise _fail(
                domain,
                "extras",
                f"returned {name!r}: {shown[:80]} for unit {unit.name!r}; {allowed}",
            )
        checked[name] = float(value)
    return checked
