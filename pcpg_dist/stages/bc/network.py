"""The BC network's shape and its starting parameters, shared by both training engines.

Why shared: the torch and numba engines must start every cell from the same numbers (a cell
trained by either engine, alone or in a batch, starts equal), and both add the same large
negative number to invalid actions' logits.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pcpg_dist.common.errors import DataError
from pcpg_dist.config.stages import BCConfig
from pcpg_dist.stages.ranking import Cell

INVALID_LOGIT = (
    -1e9
)  # added to invalid actions' logits: exp underflows to exactly 0, gradients stay finite


def layer_sizes(state_dim: int, n_actions: int, cfg: BCConfig) -> tuple[int, ...]:
    return (state_dim, *([cfg.hidden_size] * cfg.hidden_layers), n_actions)


def init_params(sizes: Sequence[int], seed: int) -> list[np.ndarray]:
    """PyTorch's default Linear init, U(+-1/sqrt(fan_in)) for weights and biases, from one seed.

    NumPy's PCG64 gives the same numbers on every platform and device, and a cell's
    initialisation depends on its seed alone, so training it alone or in a batch starts equal.
    """
    rng = np.random.default_rng([0x5EED, int(seed)])
    out = []
    for fan_in, fan_out in zip(sizes[:-1], sizes[1:], strict=True):
        bound = 1.0 / np.sqrt(fan_in)
        out.append(rng.uniform(-bound, bound, (fan_in, fan_out)))
        out.append(rng.uniform(-bound, bound, fan_out))
    return out


def start_vector(sizes: tuple[int, ...], cell: Cell, given: list[np.ndarray] | None) -> np.ndarray:
    """A cell's starting parameters as one flat vector: ``given`` (checked) or its seeded init."""
    if given is None:
        return np.concatenate([p.ravel() for p in init_params(sizes, cell.spec.seed)])
    want = [
        (a, b) if i % 2 == 0 else (b,)
        for a, b in zip(sizes[:-1], sizes[1:], strict=True)
        for i in range(2)
    ]
    got = [tuple(np.shape(p)) for p in given]
    if got != want:
        raise DataError(
            f"cell {cell.key}: starting parameters have shapes {got}, the network needs {want}"
        )
    return np.concatenate([np.asarray(p, np.float64).ravel() for p in given])
