"""A trained ensemble of BC policies: inference, joining and splitting, and its files.

Why one class for all of them: the ensemble's parameters are stacked arrays (cell ``i`` is row
``i`` of every array), so selecting, joining, saving and predicting all index the same layout;
keeping them together keeps that layout in one place.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from pcpg_dist.common.errors import ConfigError, DataError, first_line
from pcpg_dist.domains.base import Policy
from pcpg_dist.stages.bc.validation import check_cells, check_valid
from pcpg_dist.stages.ranking import Cell, CellSpec


@dataclass(frozen=True, eq=False)
class TrainedCells:
    """A trained ensemble: cell ``i`` is ``params[name][i]`` with ``mean[i]``/``std[i]`` inputs.

    Parameters are plain NumPy arrays so a Ray task can return them cheaply; ``W{l}`` has shape
    (cells, in, out) and ``b{l}`` (cells, out).
    """

    specs: tuple[CellSpec, ...]
    sizes: tuple[int, ...]  # layer widths, input first, actions last
    activation: str
    params: dict[str, np.ndarray]
    mean: np.ndarray  # (cells, d)
    std: np.ndarray  # (cells, d)
    final_loss: np.ndarray  # (cells,)

    #: the files :meth:`save` writes for ``path`` = ``.../cells`` (what a task returns as bytes)
    FILES: ClassVar[tuple[str, str]] = ("cells.pt", "cells.json")

    @classmethod
    def of_cells(
        cls,
        cells: Sequence[Cell],
        sizes: tuple[int, ...],
        activation: str,
        params: dict[str, np.ndarray],
        losses: np.ndarray,
    ) -> TrainedCells:
        """The ensemble of ``cells`` (their specs and input scales) with these parameters."""
        return cls(
            tuple(c.spec for c in cells),
            sizes,
            activation,
            params,
            np.stack([c.mean for c in cells]),
            np.stack([c.std for c in cells]),
            np.asarray(losses),
        )

    @property
    def keys(self) -> list[str]:
        return [s.key for s in self.specs]

    @property
    def state_dim(self) -> int:
        return self.sizes[0]

    @property
    def n_actions(self) -> int:
        return self.sizes[-1]

    def index(self, key: str) -> int:
        try:
            return self.keys.index(key)
        except ValueError:
            raise DataError(f"no trained cell named {key!r}") from None

    # ------------------------------------------------------------------ inference
    def logits(
        self, states: np.ndarray, cell: int | str, valid: np.ndarray | None = None
    ) -> np.ndarray:
        """(B, A) logits of one cell; invalid actions (where ``valid`` is given) get -inf."""
        i = self.index(cell) if isinstance(cell, str) else int(cell)
        states = np.asarray(states, np.float32)
        if states.ndim != 2 or states.shape[1] != self.state_dim:
            raise DataError(f"states must have shape (B, {self.state_dim}), got {states.shape}")
        h = (states - self.mean[i]) / self.std[i]
        n_layers = len(self.sizes) - 1
        for layer in range(n_layers):
            h = h @ self.params[f"W{layer}"][i] + self.params[f"b{layer}"][i]
            if layer < n_layers - 1:
                h = np.maximum(h, 0) if self.activation == "relu" else np.tanh(h)
        if valid is not None:
            valid = check_valid(valid, len(states), self.n_actions)
            h = np.where(valid, h, -np.inf)
        return h

    def predict(self, states: np.ndarray, valid: np.ndarray, cell: int | str) -> np.ndarray:
        """Greedy valid action per state (ties to the lowest action index)."""
        return np.argmax(self.logits(states, cell, valid), axis=1)

    def act(
        self,
        states: np.ndarray,
        valid: np.ndarray,
        cell: int | str,
        greedy: bool = True,
        rng: np.random.Generator | None = None,
    ) -> np.ndarray:
        """Actions of one cell's policy: greedy, or sampled from the softmax over valid actions."""
        lg = self.logits(states, cell, valid)
        if greedy:
            return np.argmax(lg, axis=1)
        if rng is None:
            raise ConfigError("sampled actions need an explicit rng")
        prob = np.exp(lg - lg.max(axis=1, keepdims=True))  # invalid: exp(-inf) = 0 exactly
        cdf = np.cumsum(prob, axis=1)
        u = rng.random(len(lg))[:, None] * cdf[:, -1:]
        a = (cdf <= u).sum(axis=1)
        # u can land on a zero-width step only at float edges; fall back to the greedy choice
        bad = (a >= self.n_actions) | ~np.asarray(valid, bool)[
            np.arange(len(a)), np.minimum(a, self.n_actions - 1)
        ]
        a[bad] = np.argmax(lg[bad], axis=1)
        return a

    def policy(self, cell: int | str, greedy: bool = True) -> Policy:
        """A domain :data:`~pcpg_dist.domains.base.Policy` backed by one cell."""
        i = self.index(cell) if isinstance(cell, str) else int(cell)

        def run(states: np.ndarray, valid: np.ndarray, rng: np.random.Generator) -> np.ndarray:
            return self.act(states, valid, i, greedy, rng)

        return run

    def cell_params(self, cell: int | str) -> list[np.ndarray]:
        """One cell's parameters as [W0, b0, W1, b1, ...] (what ``train_cells(init=...)`` takes)."""
        i = self.index(cell) if isinstance(cell, str) else cell
        return [self.params[f"{w}{layer}"][i] for layer in range(len(self.sizes) - 1) for w in "Wb"]

    # ------------------------------------------------------------------ combine
    def select(self, keys: Sequence[str]) -> TrainedCells:
        idx = [self.index(k) for k in keys]
        return TrainedCells(
            tuple(self.specs[i] for i in idx),
            self.sizes,
            self.activation,
            {n: v[idx] for n, v in self.params.items()},
            self.mean[idx],
            self.std[idx],
            self.final_loss[idx],
        )

    @staticmethod
    def concat(parts: Sequence[TrainedCells]) -> TrainedCells:
        """Join ensembles trained as separate groups (e.g. separate Ray tasks)."""
        if not parts:
            raise DataError("cannot concatenate an empty list of ensembles")
        first = parts[0]
        for p in parts[1:]:
            if p.sizes != first.sizes or p.activation != first.activation:
                raise DataError(
                    f"cannot join ensembles of sizes {p.sizes}/{p.activation} and "
                    f"{first.sizes}/{first.activation}"
                )
        specs = tuple(s for p in parts for s in p.specs)
        if len({s.key for s in specs}) != len(specs):
            raise DataError("joined ensembles have repeated cell keys")
        return TrainedCells(
            specs,
            first.sizes,
            first.activation,
            {n: np.concatenate([p.params[n] for p in parts]) for n in first.params},
            np.concatenate([p.mean for p in parts]),
            np.concatenate([p.std for p in parts]),
            np.concatenate([p.final_loss for p in parts]),
        )

    # ------------------------------------------------------------------ files
    def save(self, path: str | Path) -> Path:
        """``path.pt`` (a tensor state dict, loadable with ``weights_only=True``) + ``path.json``."""
        import torch  # here: the runner's driver reads FILES and joins agents without torch

        path = Path(path).with_suffix("")
        path.parent.mkdir(parents=True, exist_ok=True)
        # copies: arrays a Ray task returned are read-only views of the object store
        tensors = {
            **{n: torch.from_numpy(np.array(v, order="C")) for n, v in self.params.items()},
            "mean": torch.from_numpy(np.array(self.mean)),
            "std": torch.from_numpy(np.array(self.std)),
            "final_loss": torch.from_numpy(np.array(self.final_loss)),
        }
        torch.save(tensors, path.with_suffix(".pt"))
        meta = {
            "format": 1,
            "sizes": list(self.sizes),
            "activation": self.activation,
            "specs": [asdict(s) for s in self.specs],
        }
        path.with_suffix(".json").write_text(json.dumps(meta, indent=1))
        return path.with_suffix(".pt")

    def to_files(self) -> dict[str, bytes]:
        """What :meth:`save` writes, as ``{name: bytes}`` for :data:`FILES` (what a task returns:
        the driver only writes the bytes)."""
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            self.save(Path(tmp) / "cells")
            return {n: (Path(tmp) / n).read_bytes() for n in self.FILES}

    @staticmethod
    def from_files(parts: Sequence[dict[str, bytes]]) -> TrainedCells:
        """The ensemble of several :meth:`to_files` results, read and checked as :meth:`load`."""
        import tempfile

        from pcpg_dist.common.file_bytes import write_files

        with tempfile.TemporaryDirectory() as tmp:
            for i, files in enumerate(parts):
                write_files(Path(tmp) / str(i), files)
            return TrainedCells.concat(
                [TrainedCells.load(Path(tmp) / str(i) / "cells") for i in range(len(parts))]
            )

    @staticmethod
    def load(path: str | Path) -> TrainedCells:
        from pcpg_dist.stages.clustering.model_io import read_tensors

        path = Path(path).with_suffix("")
        # torch's own text for a file it cannot read spans lines and advises weights_only=False
        tensors = read_tensors(path.with_suffix(".pt"), "unreadable model files: ")
        try:
            meta = json.loads(path.with_suffix(".json").read_text())
            specs = tuple(CellSpec(**s) for s in meta["specs"])
            arrays = {n: t.numpy() for n, t in tensors.items()}
            n_layers = len(meta["sizes"]) - 1
            params = {f"{w}{i}": arrays[f"{w}{i}"] for i in range(n_layers) for w in "Wb"}
            cells = TrainedCells(
                specs,
                tuple(meta["sizes"]),
                meta["activation"],
                params,
                arrays["mean"],
                arrays["std"],
                arrays["final_loss"],
            )
        except Exception as e:  # noqa: BLE001 - a JSON or tensors that do not fit each other
            raise DataError(
                f"{path}: unreadable model files ({type(e).__name__}: {first_line(e)})"
            ) from None
        check_cells(path.with_suffix(".json"), cells)
        return cells
