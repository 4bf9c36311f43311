"""The domain seam: everything a stage needs from a game, behind one base class.

A domain says how to load or generate its trajectories (as :class:`~pcpg_dist.dataset.Dataset`
files, one per environment), how those become *units* of evaluation (a dataset, its held-out
trajectories and what Step A clusters), the skill score Step B ranks by, what it can add to the
evaluation (rollouts, reward distances, drawings, domain tables) and, where it can simulate, how a
policy is rolled out. State names, action names and valid-action masks travel on the Dataset
(``feature_names``, ``action_names``, a boolean ``valid`` mask of any width).

Nothing outside :mod:`pcpg_dist.domains` names a domain: the runner, tuning, `pcpg cluster` and
sweeps ask the registered object (:mod:`pcpg_dist.domains.registry`). Module imports must stay
light (numpy, pydantic): import heavy things inside the methods, so loading a config stays cheap.
See docs/writing-a-domain.md for a worked example.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np

from pcpg_dist.domains.defaults import in_process

if TYPE_CHECKING:
    from pydantic import BaseModel

    from pcpg_dist.config import ExperimentConfig
    from pcpg_dist.dataset import Dataset

#: A batched policy: ``(states (B, d) float32, valid (B, n_actions) bool, rng) -> actions (B,) int``.
#: It must only return valid actions. Rollouts of B episodes call it once per step for the live ones.
Policy = Callable[[np.ndarray, np.ndarray, np.random.Generator], np.ndarray]


@dataclass(frozen=True)
class StreamSource:
    """A log too large for one process, as the streamed pipeline reads it (``ray.data``): its
    Parquet files, the state columns, the number of actions, the steps (from the files' metadata)
    and which optional columns (``reward``, ``style``) it has. ``score`` is Step B's score
    (``return``, ``length`` or ``-length``); ``max_epochs`` caps BC's passes over the rows.

    A local log names its ``parts`` (small dicts of plain values: a Parquet file's row group, a
    Minari dataset's run of episodes) and ``read_part(part, columns)``, a module-level function
    that yields a part's rows as Arrow tables of those columns, run inside the engine's block tasks
    on the driver's node; ``files`` names what identifies the data on disk (for lineage). Without
    parts, ``files`` are Parquet files Ray Data reads on any node (shared storage)."""

    name: str
    files: tuple[str, ...]
    states: tuple[str, ...]
    n_actions: int
    steps: int
    optional: tuple[str, ...] = ()
    score: str = "return"
    max_epochs: int = 20
    parts: tuple[dict[str, Any], ...] = ()
    read_part: Callable[[dict[str, Any], list[str]], Iterator[Any]] | None = None


#: A domain's own skill score: one float per trajectory, higher = more skilled.
ScoreFn = Callable[["Dataset"], np.ndarray]


class FanOut(Protocol):
    """How a domain spreads its data generation over workers without knowing who they are:
    ``fan_out(fn, calls, description, show_progress=True) -> [fn(*args) for args in calls]``."""

    def __call__(
        self,
        fn: Callable[..., Any],
        calls: Sequence[tuple],
        description: str,
        show_progress: bool = True,
    ) -> list[Any]: ...


@dataclass(frozen=True)
class PaperResults:
    """What the PCPG paper reports for a domain, kept with the domain so the report names none.

    ``numbers``: the paper's figures by item (e.g. ``"clustering accuracy"``), shown beside a run's.
    ``protocol``: ``(config key, the paper's value)`` for the settings of this domain a run must
    use to be a reproduction (the settings every domain shares are the report's own).
    ``absent_means``: the value a protocol setting had in runs logged before it existed."""

    numbers: dict[str, str] = field(default_factory=dict)
    protocol: tuple[tuple[str, object], ...] = ()
    absent_means: dict[str, object] = field(default_factory=dict)


def random_policy(states: np.ndarray, valid: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Uniform choice among the valid actions of each state."""
    u = rng.random(valid.shape) * valid
    return np.argmax(u, axis=1)


@dataclass(frozen=True)
class DomainHooks:
    """What a simulating domain lends the evaluation (all optional).

    ``rollout(policy, n_episodes, rng) -> Dataset``; ``returns(dataset, style) -> (n,)``
    undiscounted return per trajectory under R_style; ``optimal_return(style) -> float``;
    ``draw(ax, dataset_of_one_trajectory)`` draws a trajectory (Fig. 8).
    """

    rollout: Callable[[Policy, int, np.random.Generator], Dataset] | None = None
    returns: Callable[[Dataset, int], np.ndarray] | None = None
    optimal_return: Callable[[int], float] | None = None
    draw: Callable[..., None] | None = None


@dataclass(frozen=True, eq=False)
class Unit:
    """One evaluation unit: a dataset, its held-out trajectories, and the name results go under."""

    name: str
    dataset: Dataset
    test_idx: np.ndarray
    #: what Step A clusters, when it differs from ``dataset`` (same trajectories, same order)
    cluster_input: Dataset | None = None
    #: names the preprocessing of ``cluster_input`` in content keys ("raw" = none)
    cluster_input_note: str = "raw"

    @property
    def clustered(self) -> Dataset:
        return self.cluster_input if self.cluster_input is not None else self.dataset

    @property
    def train_idx(self) -> np.ndarray:
        return np.setdiff1d(np.arange(self.dataset.n_trajectories), self.test_idx)


def standardised(ds: Dataset) -> Dataset:
    """The dataset with every state feature standardised over its own rows (constant ones kept at 0)."""
    mean, std = ds.states.mean(axis=0), ds.states.std(axis=0)
    std = np.where(std > 1e-6, std, 1.0)
    return replace(ds, states=((ds.states - mean) / std).astype(np.float32))


class Domain:
    """Base class of every domain; override what your game has, keep the defaults for the rest.

    Required: :attr:`name` and :meth:`generate`. A domain with settings declares its config
    sections in :attr:`sections` ({YAML key: pydantic model}; its own settings sit under its name),
    or, shorter, one model as :attr:`settings_model` (the section named after the domain).
    """

    name: ClassVar[str] = ""
    #: this domain's config sections, {YAML key: pydantic model}; the one named after the domain
    #: holds its settings (:meth:`settings`)
    sections: ClassVar[dict[str, type[BaseModel]]] = {}
    #: a domain's one settings model, for its section named after the domain (used when
    #: ``sections`` is left empty)
    settings_model: ClassVar[type[BaseModel] | None] = None
    #: what the PCPG paper reports for this domain (its numbers and protocol, shown beside ours in
    #: reports); None where the paper has no results for it (every plugin)
    paper: ClassVar[PaperResults | None] = None

    # ------------------------------------------------------------------ config
    @classmethod
    def section_models(cls) -> dict[str, type[BaseModel]]:
        """This domain's config sections: :attr:`sections`, else ``{name: settings_model}``, so a
        domain with one model needs no dict (and plugins written before ``sections`` still work)."""
        if cls.sections:
            return dict(cls.sections)
        return {cls.name: cls.settings_model} if cls.settings_model is not None else {}

    def config_sections(self) -> tuple[str, ...]:
        """The config sections this domain reads (a config holds only these besides the core)."""
        return tuple(self.section_models())

    def settings(self, cfg: ExperimentConfig) -> Any:
        """This domain's settings in ``cfg``: its section named after it, validated when ``cfg``
        was loaded (None when it has none)."""
        return getattr(cfg, self.name) if self.name in self.section_models() else None

    def check_config(self, cfg: ExperimentConfig) -> None:
        """Cheap checks when a config is loaded (files exist, ...); raise PcpgError or ValueError.

        The default validates the settings and calls their ``check()`` if they have one.
        """
        settings = self.settings(cfg)
        if hasattr(settings, "check"):
            settings.check()

    # ------------------------------------------------------------------ data
    def data_key(self, cfg: ExperimentConfig) -> list[Any]:
        """JSON-able parts that identify the data (cache key): settings, the base seed and, for a
        plugin, its package version (an upgrade regenerates the data). Include the *content* of any
        file the data is read from (a hash), not only its path."""
        settings = self.settings(cfg)
        return [
            self.name,
            cfg.seed,
            settings.model_dump(mode="json") if settings is not None else None,
            self.package_version(),
        ]

    def evaluation_key(self, cfg: ExperimentConfig) -> list[Any]:
        """JSON-able parts beyond the evaluation settings that change the evaluation's numbers
        (a rollout env's settings): part of the evaluation's cache key. Default: none."""
        return []

    def data_source(self, cfg: ExperimentConfig) -> dict[str, Any]:
        """Where the data comes from, for lineage (MLflow's dataset inputs): ``name`` (short,
        shown in the runs table), ``type`` (``"generated"``: made from settings and a seed;
        ``"local"``: read from files; or a scheme of the domain's own) and ``source`` (a JSON-able
        mapping: a ``uri`` for files, the generator's settings and seed for generated data).
        Default: generated by this domain from its settings and the base seed."""
        settings = self.settings(cfg)
        return {
            "name": f"{self.name} data",
            "type": "generated",
            "source": {
                "generator": self.name,
                "seed": cfg.seed,
                "settings": settings.model_dump(mode="json") if settings is not None else None,
                "package": self.package_version(),
            },
        }

    def stream_source(self, cfg: ExperimentConfig) -> StreamSource | None:
        """The log to stream through ``ray.data`` instead of loading it into one process (a run
        of one unit over blocks: docs/scale.md), or None. Default: None, the in-memory pipeline."""
        return None

    def package_version(self) -> str | None:
        """Version of the installed distribution that ships this domain (None for pcpg's own)."""
        from importlib.metadata import PackageNotFoundError, packages_distributions, version

        top = type(self).__module__.split(".")[0]
        if top == "pcpg_dist":
            return None
        try:
            return ",".join(
                f"{d}=={version(d)}" for d in sorted(packages_distributions().get(top, []))
            )
        except PackageNotFoundError:
            return None

    def generate(
        self, cfg: ExperimentConfig, show_progress: bool = True, fan_out: FanOut = in_process
    ) -> dict[str, Dataset]:
        """Every dataset of the config, keyed by environment name. Batches of independent calls
        go through ``fan_out(fn, calls, description, show_progress=...)`` (results in call order):
        pcpg passes one that runs them as Ray tasks, so the domain never imports Ray itself."""
        raise NotImplementedError(f"domain {self.name!r} does not generate or load data")

    def manifest(self, cfg: ExperimentConfig, datasets: dict[str, Dataset]) -> dict[str, Any]:
        """Extra provenance for the data's manifest.json (seeds, source files, ...)."""
        return {"seed_entropy": {"base": cfg.seed}}

    def units(self, cfg: ExperimentConfig, datasets: dict[str, Dataset]) -> list[Unit]:
        """Evaluation units; default: one per dataset with a seeded trajectory split
        (``ranking.test_fraction``, ``ranking.split_seed``)."""
        from pcpg_dist.domains.defaults import split_trajectories

        return [
            Unit(
                env,
                ds,
                split_trajectories(
                    ds.n_trajectories, cfg.ranking.test_fraction, cfg.ranking.split_seed
                )[1],
            )
            for env, ds in datasets.items()
        ]

    # ------------------------------------------------------------------ stages
    def score(self, cfg: ExperimentConfig) -> ScoreFn | None:
        """Step B's skill score; None = the paper's Performance (Eq. 3: goal reached, shorter first)."""
        return None

    def hooks(self, cfg: ExperimentConfig, unit: str) -> DomainHooks | None:
        """Rollouts, returns, optimal returns and drawings for one unit, where the domain simulates."""
        return None

    def extras(
        self, cfg: ExperimentConfig, unit: Unit, labels: np.ndarray, trained: Any, out: Path
    ) -> dict[str, float]:
        """Domain-specific tables written to ``out`` and their metrics (outcomes, profiles, ...)."""
        return {}
