"""The config models of all stages in one import, for the many callers that take several
(``from pcpg_dist.config.stages import BCConfig``): a plain re-export of the per-stage modules
(:mod:`.clustering`, :mod:`.ranking`, :mod:`.bc`, :mod:`.evaluation`, :mod:`.tuning`,
:mod:`.runner`), the shared bounds (:mod:`.limits`) and the clusterer table (:mod:`.clusterers`).

Each stage module imports its model from here or from its own module and re-exports it; never the
reverse.
"""

from pcpg_dist.config.bc import BCConfig
from pcpg_dist.config.clusterers import LIKELIHOOD_METHODS, NEURAL_CLUSTERERS
from pcpg_dist.config.clustering import ClusterConfig
from pcpg_dist.config.evaluation import EvalConfig
from pcpg_dist.config.limits import MAX_COUNT, MAX_EPISODE_STEPS, MAX_SEED
from pcpg_dist.config.ranking import DEFAULT_PS, RankConfig
from pcpg_dist.config.runner import RunnerConfig
from pcpg_dist.config.tuning import PARAMS, TARGETS, TuneConfig

__all__ = [
    "BCConfig",
    "ClusterConfig",
    "DEFAULT_PS",
    "EvalConfig",
    "LIKELIHOOD_METHODS",
    "MAX_COUNT",
    "MAX_EPISODE_STEPS",
    "MAX_SEED",
    "NEURAL_CLUSTERERS",
    "PARAMS",
    "RankConfig",
    "RunnerConfig",
    "TARGETS",
    "TuneConfig",
]
