"""Where BC trains (device) and with which engine (torch or the numba kernel).

Why its own module: the runner asks where a unit trains before it trains anything (to place Ray
tasks on CPUs or a GPU), without importing either engine.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pcpg_dist.common.devices import resolve_device
from pcpg_dist.common.errors import ConfigError
from pcpg_dist.config.stages import BCConfig

if TYPE_CHECKING:  # torch is imported where a device is made: the runner's driver never does
    import torch


def runs_on_cpu_only(cfg: BCConfig) -> bool:
    """Minibatches (an explicit ``batch_size``) and the numba kernel are CPU-only: ``auto`` then
    means the CPU (``batch_size: auto`` trains full batch where the torch engine runs)."""
    return isinstance(cfg.batch_size, int) or cfg.engine == "numba"


def bc_device(cfg: BCConfig) -> torch.device:
    """Where ``cfg`` trains: ``bc.device``, with ``auto`` on the CPU for CPU-only settings."""
    import torch

    if cfg.device == "auto" and runs_on_cpu_only(cfg):
        return torch.device("cpu")
    return resolve_device(cfg.device, "bc.device")


def choose_engine(cfg: BCConfig, device: torch.device) -> str:
    """``torch`` or ``numba`` for ``cfg`` on ``device`` (``auto``: numba on the CPU in float32);
    a ConfigError for a setting the chosen engine cannot run, before any training starts."""
    if cfg.engine == "numba" and (device.type != "cpu" or cfg.dtype != "float32"):
        raise ConfigError(
            "bc.engine 'numba' runs on the CPU in float32 only "
            f"(got device {device.type}, dtype {cfg.dtype})"
        )
    engine = cfg.engine
    if engine == "auto":
        engine = "numba" if device.type == "cpu" and cfg.dtype == "float32" else "torch"
    if engine == "torch" and isinstance(cfg.batch_size, int):
        raise ConfigError(
            f"bc.batch_size={cfg.batch_size} needs the numba engine (CPU, float32); "
            f"got engine {engine} on {device.type} in {cfg.dtype}: set bc.batch_size: null"
        )
    return engine
