"""Step C: behavioural cloning of many small policies in one vectorised pass.

Why vectorised: a 3x5 MLP is microseconds of arithmetic, so a per-model training loop is all
Python and autograd overhead. Here every cell's parameters are one slice of stacked tensors,
the forward and backward passes are hand-written ``torch.baddbmm``/``bmm`` calls over all cells at
once (cells padded to a common row count with zero-weight rows), and Adam runs on one flat
(cells, params) buffer. Adam is elementwise, so a stacked Adam is exactly independent Adams; the
loss of each cell is the weighted mean over its own rows, so padding and neighbours cannot leak
into it. Training is full batch and deterministic: the only randomness is the initialisation,
drawn from each cell's own seed.

Cells are grouped into buckets of similar row counts before padding, so a few large cells (No
Clustering at p = 1) do not make every small cell pay for their padding.
"""

from __future__ import annotations

import json
import reprlib
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from pcpg_dist.common.devices import resolve_device
from pcpg_dist.common.errors import ConfigError, DataError, TrainingError, first_line
from pcpg_dist.config.stages import BCConfig
from pcpg_dist.domains.base import Policy
from pcpg_dist.stages.ranking import Cell, CellSpec, dedupe_rows

ACTIVATIONS = ("relu", "tanh")  # BCConfig.activation's values (both have an ONNX operator)
CELL_KINDS = ("pcpg", "nc", "corrupt")  # CellSpec.kind
_NEG = -1e9  # added to invalid actions' logits: exp underflows to exactly 0, gradients stay finite


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
            valid = _check_valid(valid, len(states), self.n_actions)
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

    @staticmethod
    def load(path: str | Path) -> TrainedCells:
        from pcpg_dist.stages.clustering.models import read_tensors

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


def check_cells(source: Path | str, cells) -> None:
    """A DataError naming ``source`` unless the cells' JSON (specs, sizes, activation) agrees
    with their weights: one spec per weight set, ``W{l}`` of shape (cells, sizes[l], sizes[l+1]),
    ``b{l}`` (cells, sizes[l+1]), mean and std (cells, sizes[0]), p in (0, 1]."""
    sizes, n = cells.sizes, len(cells.specs)
    if len(sizes) < 2 or not all(_whole(x) and x >= 1 for x in sizes):
        raise DataError(
            f"{source}: sizes {reprlib.repr(list(sizes))} must be a list of at least two "
            f"positive whole numbers (state width, hidden widths, n_actions)"
        )
    if cells.activation not in ACTIVATIONS:
        raise DataError(
            f"{source}: activation {reprlib.repr(cells.activation)} is not one of "
            f"{', '.join(ACTIVATIONS)}"
        )
    if n == 0:
        raise DataError(f"{source}: specs is empty; the file must list one spec per trained cell")
    for i, s in enumerate(cells.specs):
        _check_spec(f"{source}: specs[{i}]", s)
    if len({s.key for s in cells.specs}) != n:
        raise DataError(f"{source}: specs repeat a cell key; each cell needs its own")
    arrays = []
    for layer in range(len(sizes) - 1):
        arrays += [
            (f"W{layer}", cells.params[f"W{layer}"], (n, sizes[layer], sizes[layer + 1])),
            (f"b{layer}", cells.params[f"b{layer}"], (n, sizes[layer + 1])),
        ]
    arrays += [
        ("mean", cells.mean, (n, sizes[0])),
        ("std", cells.std, (n, sizes[0])),
        ("final_loss", cells.final_loss, (n,)),
    ]
    for name, value, want in arrays:
        shape = np.shape(value)
        if shape[:1] != want[:1]:
            raise DataError(
                f"{source}: {n} specs for {shape[0] if shape else 0} weight sets ({name} "
                f"has shape {shape}); the file must list one spec per trained cell"
            )
        if shape != want or not np.issubdtype(np.asarray(value).dtype, np.floating):
            raise DataError(
                f"{source}: {name} has shape {shape} ({np.asarray(value).dtype}), but sizes "
                f"{list(sizes)} need {want} floats"
            )
        if name != "final_loss" and not np.isfinite(value).all():
            raise DataError(
                f"{source}: {name} holds non-finite values (NaN or inf); a trained agent's "
                f"weights are finite"
            )
    if (np.asarray(cells.std) <= 0).any():
        raise DataError(
            f"{source}: std holds values <= 0; the input scale of every feature must be positive"
        )


def _check_spec(where: str, s) -> None:
    if not isinstance(s.key, str) or not s.key:
        raise DataError(f"{where}: key {reprlib.repr(s.key)} must be a non-empty string")
    if s.kind not in CELL_KINDS:
        raise DataError(
            f"{where}: kind {reprlib.repr(s.kind)} is not one of {', '.join(CELL_KINDS)}"
        )
    for field in ("k", "seed"):
        if not _whole(getattr(s, field)):
            raise DataError(
                f"{where}: {field} {reprlib.repr(getattr(s, field))} must be a whole number"
            )
    if not _number(s.p) or not 0 < s.p <= 1:
        raise DataError(f"{where}: p {reprlib.repr(s.p)} must be a number in (0, 1]")
    if not _number(s.c) or not 0 <= s.c <= 1:
        raise DataError(f"{where}: c {reprlib.repr(s.c)} must be a number in [0, 1]")


def _whole(x) -> bool:
    return isinstance(x, int | np.integer) and not isinstance(x, bool)


def _number(x) -> bool:
    finite_number = isinstance(x, int | float | np.integer | np.floating) and not isinstance(
        x, bool
    )
    return finite_number and bool(np.isfinite(x))


def _check_valid(valid: np.ndarray, rows: int, n_actions: int) -> np.ndarray:
    valid = np.asarray(valid, bool)
    if valid.shape != (rows, n_actions):
        raise DataError(f"valid must have shape ({rows}, {n_actions}), got {valid.shape}")
    if rows and not valid.any(axis=1).all():
        raise DataError("a state has no valid action")
    return valid


# ---------------------------------------------------------------------- training
def runs_on_cpu_only(cfg: BCConfig) -> bool:
    """Minibatches (``batch_size``) and the numba kernel are CPU-only: ``auto`` then means the CPU."""
    return cfg.batch_size is not None or cfg.engine == "numba"


def bc_device(cfg: BCConfig) -> torch.device:
    """Where ``cfg`` trains: ``bc.device``, with ``auto`` on the CPU for CPU-only settings."""
    if cfg.device == "auto" and runs_on_cpu_only(cfg):
        return torch.device("cpu")
    return resolve_device(cfg.device, "bc.device")


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


def buckets(rows: Sequence[int], overhead: int) -> list[list[int]]:
    """Group cells (by index) into runs of similar row counts, minimising padded rows plus
    ``overhead`` per group (a dynamic programme over the cells sorted by size)."""
    order = sorted(range(len(rows)), key=lambda i: rows[i])
    sizes = [rows[i] for i in order]
    n = len(sizes)
    best = [0.0] + [float("inf")] * n
    cut = [0] * (n + 1)
    for j in range(1, n + 1):  # group order[i:j] is padded to sizes[j-1]
        for i in range(j):
            cost = best[i] + overhead + (j - i) * sizes[j - 1]
            if cost < best[j]:
                best[j], cut[j] = cost, i
    groups, j = [], n
    while j > 0:
        groups.append(order[cut[j] : j])
        j = cut[j]
    return groups[::-1]


def train_cells(
    cells: Sequence[Cell], cfg: BCConfig, init: Sequence[list[np.ndarray] | None] | None = None
) -> TrainedCells:
    """Train one policy per cell; pure and deterministic (what one Ray task runs on a group).

    ``init[i]``, where given, is cell i's starting parameters (W0, b0, W1, b1, ...; e.g. a
    trained No Clustering agent to fine-tune) instead of the seeded initialisation.
    """
    if not cells:
        raise DataError("no cells to train")
    d, n_actions = cells[0].state_dim, cells[0].n_actions
    for c in cells:
        if c.state_dim != d or c.n_actions != n_actions:
            raise DataError(
                f"cell {c.key} has state width {c.state_dim} and {c.n_actions} actions; "
                f"cell {cells[0].key} has {d} and {n_actions}: train them separately"
            )
    if len({c.key for c in cells}) != len(cells):
        raise DataError("cell keys must be unique")
    data = [
        dedupe_rows(c.states, c.valid, c.actions, c.weights)
        if cfg.dedupe
        else (c.states, c.valid, c.actions, c.weights)
        for c in cells
    ]
    sizes = layer_sizes(d, n_actions, cfg)
    if init is not None and len(init) != len(cells):
        raise DataError(
            f"{len(init)} starting parameter sets for {len(cells)} cells: give one per cell (None: seeded)"
        )
    starts = [_start(sizes, c, None if init is None else init[i]) for i, c in enumerate(cells)]
    device = bc_device(cfg)
    dtype = torch.float32 if cfg.dtype == "float32" else torch.float64
    params = {
        f"{w}{i}": np.zeros((len(cells), *((a, b) if w == "W" else (b,))), np.float32)
        for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True))
        for w in "Wb"
    }
    losses = np.zeros(len(cells))
    if _engine(cfg, device) == "numba":
        trained, losses = _train_numba(cells, data, sizes, cfg, starts)
        check_finite(cells, trained, losses, cfg)
        return TrainedCells(
            tuple(c.spec for c in cells),
            sizes,
            cfg.activation,
            trained,
            np.stack([c.mean for c in cells]),
            np.stack([c.std for c in cells]),
            losses,
        )
    for group in buckets([len(x[2]) for x in data], cfg.bucket_overhead_rows):
        trained, loss = _train_group(
            [cells[i] for i in group],
            [data[i] for i in group],
            sizes,
            cfg,
            device,
            dtype,
            [starts[i] for i in group],
        )
        for name, value in trained.items():
            params[name][group] = value
        losses[group] = loss
    check_finite(cells, params, losses, cfg)
    return TrainedCells(
        tuple(c.spec for c in cells),
        sizes,
        cfg.activation,
        params,
        np.stack([c.mean for c in cells]),
        np.stack([c.std for c in cells]),
        losses,
    )


def split_for_init(cells: Sequence[Cell], cfg: BCConfig) -> tuple[list[Cell], list[Cell]]:
    """(cells that start from their seeded init, cells that start from a No Clustering agent):
    with ``bc.init: no_clustering`` the No Clustering cells train first, the others after."""
    if cfg.init == "scratch":
        return list(cells), []
    return [c for c in cells if c.spec.kind == "nc"], [c for c in cells if c.spec.kind != "nc"]


def init_from(cells: Sequence[Cell], base: TrainedCells) -> list[list[np.ndarray]]:
    """Each cell's starting parameters: the No Clustering agent in ``base`` of its p and seed."""
    table = {(s.p, s.seed): i for i, s in enumerate(base.specs) if s.kind == "nc"}
    missing = [c.key for c in cells if (c.spec.p, c.spec.seed) not in table]
    if missing:
        raise DataError(
            f"bc.init no_clustering: cell {missing[0]} has no No Clustering agent of "
            "its p and seed to start from"
        )
    return [base.cell_params(table[(c.spec.p, c.spec.seed)]) for c in cells]


def finetune_config(cfg: BCConfig) -> BCConfig:
    """The settings of the cells that start from No Clustering (``finetune_epochs`` epochs)."""
    return (
        cfg
        if cfg.finetune_epochs is None
        else cfg.model_copy(update={"epochs": cfg.finetune_epochs})
    )


def train_plan(cells: Sequence[Cell], cfg: BCConfig) -> TrainedCells:
    """Train a unit's planned cells in this process, honouring ``bc.init`` (the runner does the
    same as two rounds of Ray tasks)."""
    first, rest = split_for_init(cells, cfg)
    base = train_cells(first, cfg)
    if not rest:
        return base
    tuned = train_cells(rest, finetune_config(cfg), init_from(rest, base))
    return TrainedCells.concat([base, tuned]).select([c.key for c in cells])


def _start(sizes: tuple[int, ...], cell: Cell, given: list[np.ndarray] | None) -> np.ndarray:
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


def check_finite(
    cells: Sequence[Cell], params: dict[str, np.ndarray], losses: np.ndarray, cfg: BCConfig
) -> None:
    """Diverged training (NaN or infinite weights or loss) stops the run: such a policy must never
    be evaluated, cached or published as an agent."""
    bad = ~np.isfinite(np.asarray(losses, np.float64))
    for value in params.values():
        bad |= ~np.isfinite(value.reshape(len(cells), -1)).all(axis=1)
    if bad.any():
        first = int(np.argmax(bad))
        raise TrainingError(
            f"BC training diverged for {int(bad.sum())} of {len(cells)} cells (first: "
            f"{cells[first].key}): non-finite weights or loss with bc.lr={cfg.lr}, "
            f"bc.betas={list(cfg.betas)}, bc.eps={cfg.eps}, bc.dtype={cfg.dtype}; lower bc.lr "
            f"or check the data's state features for huge values"
        )


def _engine(cfg: BCConfig, device: torch.device) -> str:
    if cfg.engine == "numba" and (device.type != "cpu" or cfg.dtype != "float32"):
        raise ConfigError(
            "bc.engine 'numba' runs on the CPU in float32 only "
            f"(got device {device.type}, dtype {cfg.dtype})"
        )
    engine = cfg.engine
    if engine == "auto":
        engine = "numba" if device.type == "cpu" and cfg.dtype == "float32" else "torch"
    if engine == "torch" and cfg.batch_size is not None:
        raise ConfigError(
            f"bc.batch_size={cfg.batch_size} needs the numba engine (CPU, float32); "
            f"got engine {engine} on {device.type} in {cfg.dtype}: set bc.batch_size: null"
        )
    return engine


def _thread_schedule(rows: Sequence[int], slots: int) -> tuple[np.ndarray, np.ndarray]:
    """Longest-first assignment of cells to thread slots, so no thread idles while one works."""
    load = [0] * slots
    bins: list[list[int]] = [[] for _ in range(slots)]
    for i in sorted(range(len(rows)), key=lambda i: -rows[i]):
        t = int(np.argmin(load))
        bins[t].append(i)
        load[t] += rows[i] + 50  # + a fixed per-cell cost
    return (
        np.array([i for b in bins for i in b], np.int64),
        np.r_[0, np.cumsum([len(b) for b in bins])].astype(np.int64),
    )


def _train_numba(
    cells: Sequence[Cell],
    data: list[tuple[np.ndarray, ...]],
    sizes: tuple[int, ...],
    cfg: BCConfig,
    starts: list[np.ndarray],
) -> tuple[dict, np.ndarray]:
    import numba

    from pcpg_dist.stages.bc_kernel import train_kernel

    n_layers = len(sizes) - 1
    if cfg.batch_size is not None:  # minibatches are blocks of one fixed shuffle per cell
        data = [
            tuple(a[order] for a in x)
            for x, order in (
                (x, np.random.default_rng([c.spec.seed, 1]).permutation(len(x[2])))
                for c, x in zip(cells, data, strict=True)
            )
        ]
    rows = [len(x[2]) for x in data]
    row_off = np.r_[0, np.cumsum(rows)].astype(np.int64)
    xt = np.concatenate([(s - c.mean) / c.std for c, (s, _, _, _) in zip(cells, data, strict=True)])
    neg = np.concatenate([np.where(v, 0.0, _NEG) for _, v, _, _ in data]).astype(np.float32)
    acts = np.concatenate([a for _, _, a, _ in data]).astype(np.int64)
    wn = np.concatenate([w / w.sum() for _, _, _, w in data]).astype(np.float32)
    theta = np.stack(starts).astype(np.float32)
    numel = [x for a, b in zip(sizes[:-1], sizes[1:], strict=True) for x in (a * b, b)]
    offs = np.r_[0, np.cumsum(numel)].astype(np.int64)
    # follow the thread count the caller gave torch (parallel.set_threads): an oversubscribed
    # prange on a busy machine waits for its slowest thread
    numba.set_num_threads(max(1, min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS)))
    schedule, sched_off = _thread_schedule(rows, numba.get_num_threads())
    losses = np.zeros(len(cells))
    train_kernel(
        np.ascontiguousarray(xt.T, np.float32),
        np.ascontiguousarray(neg.T),
        acts,
        wn,
        row_off,
        theta,
        np.array(sizes, np.int64),
        offs[0:-1:2].copy(),
        offs[1::2].copy(),
        cfg.epochs,
        cfg.lr,
        cfg.betas[0],
        cfg.betas[1],
        cfg.eps,
        cfg.activation == "relu",
        schedule,
        sched_off,
        losses,
        cfg.batch_size or 0,
    )
    out = {}
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        out[f"W{i}"] = theta[:, offs[2 * i] : offs[2 * i + 1]].reshape(-1, a, b).copy()
        out[f"b{i}"] = theta[:, offs[2 * i + 1] : offs[2 * i + 2]].copy()
    del n_layers
    return out, losses


def _train_group(
    cells: list[Cell],
    data: list[tuple[np.ndarray, ...]],
    sizes: tuple[int, ...],
    cfg: BCConfig,
    device: torch.device,
    dtype: torch.dtype,
    starts: list[np.ndarray],
) -> tuple[dict, np.ndarray]:
    n_cells, n_rows = len(cells), max(len(x[2]) for x in data)
    d, n_actions = sizes[0], sizes[-1]
    x = np.zeros((n_cells, n_rows, d), np.float32)
    neg = np.zeros((n_cells, n_rows, n_actions), np.float32)  # padding rows: all valid, weight 0
    target = np.zeros((n_cells, n_rows, n_actions), np.float64)
    weight = np.zeros((n_cells, n_rows, 1), np.float64)
    for j, (cell, (s, v, a, w)) in enumerate(zip(cells, data, strict=True)):
        n = len(a)
        x[j, :n] = (s - cell.mean) / cell.std
        neg[j, :n] = np.where(v, 0.0, _NEG)
        wn = w / w.sum()  # each cell's loss is the mean over its own samples
        weight[j, :n, 0] = wn
        target[j, np.arange(n), a] = wn

    def t(a: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(a, dtype=dtype, device=device)

    x, neg, target, weight = t(x), t(neg), t(target), t(weight)
    # one flat (cells, P) buffer for parameters, gradients and Adam moments; W/b are views into it
    shapes = [
        (a, b) if i % 2 == 0 else (1, b)
        for a, b in zip(sizes[:-1], sizes[1:], strict=True)
        for i in range(2)
    ]
    numel = [a * b for a, b in shapes]
    offs = np.r_[0, np.cumsum(numel)]
    flat = np.stack(starts)
    theta, grad = t(flat), torch.zeros(n_cells, int(offs[-1]), dtype=dtype, device=device)
    m, v = torch.zeros_like(theta), torch.zeros_like(theta)

    def views(buf: torch.Tensor) -> list[torch.Tensor]:
        return [buf[:, offs[i] : offs[i + 1]].view(n_cells, *shapes[i]) for i in range(len(shapes))]

    ps, gs = views(theta), views(grad)
    relu = cfg.activation == "relu"
    act_back = (
        torch.ops.aten.threshold_backward.default if relu else torch.ops.aten.tanh_backward.default
    )
    n_layers = len(sizes) - 1
    beta1, beta2 = cfg.betas

    def forward() -> tuple[list[torch.Tensor], torch.Tensor]:
        hs = [x]
        for layer in range(n_layers - 1):
            z = torch.baddbmm(ps[2 * layer + 1], hs[-1], ps[2 * layer])
            hs.append(z.relu_() if relu else z.tanh_())
        logits = torch.baddbmm(ps[-1], hs[-1], ps[-2]).add_(neg)
        return hs, logits

    with torch.no_grad():
        for step in range(1, cfg.epochs + 1):
            hs, logits = forward()
            # d(weighted mean CE)/d logits = w * softmax - w * onehot
            g = torch.softmax(logits, dim=-1).mul_(weight).sub_(target)
            for layer in range(n_layers - 1, -1, -1):
                gs[2 * layer].copy_(torch.bmm(hs[layer].transpose(1, 2), g))
                gs[2 * layer + 1].copy_(g.sum(dim=1, keepdim=True))
                if layer:
                    gh = torch.bmm(g, ps[2 * layer].transpose(1, 2))
                    g = act_back(gh, hs[layer], 0) if relu else act_back(gh, hs[layer])
            # Adam, exactly as torch.optim.Adam (no weight decay, no amsgrad)
            m.mul_(beta1).add_(grad, alpha=1 - beta1)
            v.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
            bc1, bc2 = 1 - beta1**step, 1 - beta2**step
            denom = (v.sqrt() / bc2**0.5).add_(cfg.eps)
            theta.addcdiv_(m, denom, value=-cfg.lr / bc1)
        _, logits = forward()
        logp = torch.log_softmax(logits, dim=-1)
        loss = -(logp * target).sum(dim=(1, 2))
    out = {}
    host = [p.detach().cpu().numpy().astype(np.float32) for p in ps]
    for i in range(n_layers):
        out[f"W{i}"] = host[2 * i]
        out[f"b{i}"] = host[2 * i + 1][:, 0, :]
    return out, loss.cpu().numpy().astype(np.float64)


def weighted_loss_and_grad(
    cell: Cell, params: list[np.ndarray], activation: str = "relu", dedupe: bool = True
) -> tuple[float, list[np.ndarray]]:
    """The training loss of one cell and its gradient by autograd (for tests and checks).

    Independent of the hand-written backward above, so a test can compare the two and compare
    deduplicated rows against raw ones.
    """
    s, v, a, w = (
        dedupe_rows(cell.states, cell.valid, cell.actions, cell.weights)
        if dedupe
        else (cell.states, cell.valid, cell.actions, cell.weights)
    )
    ts = [torch.tensor(p, dtype=torch.float64, requires_grad=True) for p in params]
    h = torch.tensor((s - cell.mean) / cell.std, dtype=torch.float64)
    for i in range(len(ts) // 2):
        h = h @ ts[2 * i] + ts[2 * i + 1]
        if i < len(ts) // 2 - 1:
            h = torch.relu(h) if activation == "relu" else torch.tanh(h)
    h = h.masked_fill(~torch.tensor(v), float("-inf"))
    ce = torch.nn.functional.cross_entropy(h, torch.tensor(a), reduction="none")
    wt = torch.tensor(w, dtype=torch.float64)
    loss = (ce * wt).sum() / wt.sum()
    loss.backward()
    return float(loss.detach()), [p.grad.numpy() for p in ts]
