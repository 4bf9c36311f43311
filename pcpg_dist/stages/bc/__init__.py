"""Step C: behavioural cloning of many small policies at once, one per planned cell.

The package's public face; its modules, one concern each:

- :mod:`~pcpg_dist.stages.bc.trained`: :class:`TrainedCells`, the trained ensemble (inference,
  joining, files); :mod:`~pcpg_dist.stages.bc.validation` checks its files.
- :mod:`~pcpg_dist.stages.bc.train`: :func:`train_cells`, one group of cells on one engine;
  :mod:`~pcpg_dist.stages.bc.plan`: ``bc.init`` (:func:`train_plan`, fine-tuning rounds);
  :mod:`~pcpg_dist.stages.bc.finetune`: :func:`finetune_cells` and its fair check.
- :mod:`~pcpg_dist.stages.bc.device`: where and with which engine training runs.
- :mod:`~pcpg_dist.stages.bc.torch_engine` (vectorised torch, GPU or CPU),
  :mod:`~pcpg_dist.stages.bc.numba_engine` and :mod:`~pcpg_dist.stages.bc.kernel` (the compiled
  CPU kernel); :mod:`~pcpg_dist.stages.bc.network` holds what both engines share.
- :mod:`~pcpg_dist.stages.bc.reference_loss`: the autograd loss the tests check the engines with.
"""

from pcpg_dist.stages.bc.device import bc_device, runs_on_cpu_only
from pcpg_dist.stages.bc.finetune import bases_of, finetune_cells
from pcpg_dist.stages.bc.network import init_params, layer_sizes
from pcpg_dist.stages.bc.plan import finetune_config, init_from, split_for_init, train_plan
from pcpg_dist.stages.bc.reference_loss import weighted_loss_and_grad
from pcpg_dist.stages.bc.train import check_finite, train_cells
from pcpg_dist.stages.bc.trained import TrainedCells
from pcpg_dist.stages.bc.validation import ACTIVATIONS, CELL_KINDS, check_cells

__all__ = [
    "ACTIVATIONS",
    "CELL_KINDS",
    "TrainedCells",
    "bases_of",
    "bc_device",
    "check_cells",
    "check_finite",
    "finetune_cells",
    "finetune_config",
    "init_from",
    "init_params",
    "layer_sizes",
    "runs_on_cpu_only",
    "split_for_init",
    "train_cells",
    "train_plan",
    "weighted_loss_and_grad",
]
