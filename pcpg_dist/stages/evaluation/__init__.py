"""Everything the paper reports about the trained agents, for one environment at a time
(:func:`evaluate`), and across environments (:func:`summarize`).

The package's public face; its modules, one concern each: :mod:`.environment` (the evaluation
of one environment, step by step), :mod:`.context` (its inputs and outputs in progress),
:mod:`.scoring` (teacher-forced predictions, made once), :mod:`.accuracy` (Fig. 4, cluster
styles), :mod:`.cross` (Table 4, Fig. 7), :mod:`.subsets` (Fig. 6 from the data),
:mod:`.rollouts` (Table 3, Fig. 5/6/8), :mod:`.corruption` (Fig. 9, Table 5), :mod:`.writing`
(the files), :mod:`.summary` (across environments), :mod:`.results` (:class:`EvalResult`).
"""

from pcpg_dist.stages.evaluation.environment import evaluate
from pcpg_dist.stages.evaluation.results import EvalResult
from pcpg_dist.stages.evaluation.rollouts import over_seeds, rollout_rng
from pcpg_dist.stages.evaluation.scoring import Scorer, style_of_clusters
from pcpg_dist.stages.evaluation.summary import summarize

__all__ = [
    "EvalResult",
    "Scorer",
    "evaluate",
    "over_seeds",
    "rollout_rng",
    "style_of_clusters",
    "summarize",
]
