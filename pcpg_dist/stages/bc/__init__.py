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

Every name is imported when first used (as :mod:`pcpg_dist` does), so a run's driver that only
plans the cells (:func:`split_for_init`, :data:`TrainedCells.FILES`, :func:`runs_on_cpu_only`)
does not import torch or an engine: torch alone costs every ``pcpg run`` about 2 s of CPU.
"""

from __future__ import annotations

import importlib
from typing import Any

#: public name -> the module that defines it
_MODULES = {
    "bc_device": "device",
    "runs_on_cpu_only": "device",
    "bases_of": "finetune",
    "finetune_cells": "finetune",
    "init_params": "network",
    "layer_sizes": "network",
    "finetune_config": "plan",
    "init_from": "plan",
    "split_for_init": "plan",
    "train_plan": "plan",
    "weighted_loss_and_grad": "reference_loss",
    "check_finite": "train",
    "train_cells": "train",
    "TrainedCells": "trained",
    "ACTIVATIONS": "validation",
    "CELL_KINDS": "validation",
    "check_cells": "validation",
}
__all__ = sorted(_MODULES)


def __getattr__(name: str) -> Any:
    module = _MODULES.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # imported once
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
