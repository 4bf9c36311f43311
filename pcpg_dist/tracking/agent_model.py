"""The trained agents of a run as one MLflow pyfunc model (models-from-code: nothing pickled).

``mlflow.pyfunc.load_model(f"runs:/{run_id}/agents").predict(df)`` (or ``mlflow models serve``)
returns one action per row of ``df``, whose columns docs/agents.md describes: ``env``, ``style``
(k, or -1 for No Clustering), ``p``, ``seed`` (optional), ``valid`` (optional list of n_actions
booleans), ``s0..s{d-1}`` (the state). This file runs in the serving process on its own: it
imports numpy, pandas and mlflow only (no torch, no pcpg_dist), which is why the weights travel
as ``<env>.npz`` + ``<env>.json`` rather than the run's torch files. Every bad request raises
:class:`AgentRequestError`: HTTP 400 with a one-line message that names the row, the column and
what is allowed, any value cut short.
"""

from __future__ import annotations

import json
import logging
import os
import reprlib
import sys
from dataclasses import dataclass
from pathlib import Path
from zipfile import BadZipFile

import mlflow.models
import mlflow.pyfunc
import numpy as np
import pandas as pd
from mlflow.exceptions import MlflowException
from mlflow.protos.databricks_pb2 import INTERNAL_ERROR, INVALID_PARAMETER_VALUE

# One tqdm bar per artifact download (dozens of lines outside a terminal) is noise when the model
# loads in a process that imported this file: the serving process, or a user's after `load`.
os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")

NC_STYLE = -1  # the `style` of the No-Clustering baseline (top p of every trajectory)
_NO_SEED = -(2**62)  # "no seed given": the lowest trained one
_log = logging.getLogger(__name__)
REQUIREMENTS = ("mlflow", "numpy", "pandas")  # all that this file imports
_SHORT = reprlib.Repr()  # what a message shows of a request value: ~80 characters, 6 levels deep
_SHORT.maxstring = _SHORT.maxother = _SHORT.maxlong = 80


def _clip(text: str, limit: int = 500) -> str:  # one line, its middle cut out beyond limit
    line = " ".join(str(text).split())
    return line if len(line) <= limit else f"{line[: limit - 120]} … {line[-100:]}"


class OneLineError(MlflowException):
    """An error whose ``message`` stays one line, its first value cut to 500 characters: MLflow
    3.17's scoring server rewrites the message of an exception raised in predict to ``"Failed to
    predict data '<the request as a table>'. \\nError: ..."`` (lines, as long as the request)."""

    @property
    def message(self) -> str:
        return self._line

    @message.setter
    def message(self, value: str) -> None:
        if not hasattr(self, "_line"):
            self._line = _clip(value)


class AgentRequestError(OneLineError):
    """A bad request: HTTP 400, ``{"error_code": "INVALID_PARAMETER_VALUE", "message": ...}``."""

    def __init__(self, message: str) -> None:
        super().__init__(message, error_code=INVALID_PARAMETER_VALUE)


@dataclass(frozen=True)
class CellInfo:
    """What one trained cell is (the fields of ``pcpg_dist.stages.ranking.CellSpec``)."""

    key: str
    kind: str  # "pcpg", "nc" (No Clustering) or "corrupt"
    k: int  # the style (cluster index); -1 for "nc"
    p: float
    seed: int
    c: float = 0.0


def _show(v) -> str:  # a request value as the user wrote it, cut short; NumPy scalars as numbers
    return _SHORT.repr(v.item() if isinstance(v, np.generic) else v)


def _names(values) -> str:
    return ", ".join(f"{v:g}" if isinstance(v, float) else str(v) for v in values)


@dataclass(frozen=True, eq=False)
class EnvAgents:
    """Every cell of one environment as stacked NumPy arrays (as ``TrainedCells``, no torch)."""

    env: str
    specs: tuple[CellInfo, ...]
    sizes: tuple[int, ...]
    activation: str
    params: dict[str, np.ndarray]  # W{l} (cells, in, out), b{l} (cells, out)
    mean: np.ndarray  # (cells, d)
    std: np.ndarray

    @property
    def state_dim(self) -> int:
        return self.sizes[0]

    @property
    def n_actions(self) -> int:
        return self.sizes[-1]

    def predict(self, states: np.ndarray, valid: np.ndarray, cell: int) -> np.ndarray:
        """Greedy valid action of one cell: the same float32 arithmetic as ``TrainedCells``."""
        h = (states.astype(np.float32) - self.mean[cell]) / self.std[cell]
        n_layers = len(self.sizes) - 1
        for layer in range(n_layers):
            h = h @ self.params[f"W{layer}"][cell] + self.params[f"b{layer}"][cell]
            if layer < n_layers - 1:
                h = np.maximum(h, 0) if self.activation == "relu" else np.tanh(h)
        return np.argmax(np.where(valid, h, -np.inf), axis=1)

    # ------------------------------------------------------------------ picking cells
    def cell_of(self, row: int, style: int, p: float, seed: int | None) -> int:
        """The cell index of (style, p, seed), or an error listing what is trained."""
        kind = "nc" if style == NC_STYLE else "pcpg"
        picks = [(i, s) for i, s in enumerate(self.specs) if s.kind in ("pcpg", "nc")]
        styles = sorted({s.k for _, s in picks if s.kind == "pcpg"})
        same_style = [(i, s) for i, s in picks if s.kind == kind and (kind == "nc" or s.k == style)]
        where = f"row {row}: env {self.env!r}"
        if not same_style:
            raise AgentRequestError(
                f"{where}: style {style} is not trained; trained styles: "
                f"{_names(styles)} (and {NC_STYLE} = No Clustering)"
            )
        same_p = [(i, s) for i, s in same_style if abs(s.p - p) <= 1e-9 * max(1.0, abs(p))]
        if not same_p:
            ps = sorted({s.p for _, s in same_style}, reverse=True)
            raise AgentRequestError(
                f"{where}: p={p:g} is not trained for style {style}; trained p: {_names(ps)}"
            )
        if seed is None:
            return min(same_p, key=lambda x: x[1].seed)[0]
        for i, s in same_p:
            if s.seed == seed:
                return i
        raise AgentRequestError(
            f"{where}: seed {seed} is not trained for style {style} at p={p:g}; "
            f"trained seeds: {_names(sorted(s.seed for _, s in same_p))}"
        )


# ---------------------------------------------------------------------- files (agent_packaging writes them)
class AgentFileError(ValueError):
    """An ``<env>.npz`` + ``<env>.json`` pair that cannot be read: one line naming the file."""


# what a missing or garbage file, or JSON that is not the mapping write_env_agents makes, raises
_UNREADABLE = (OSError, ValueError, TypeError, KeyError, EOFError, RecursionError, BadZipFile)


def _unreadable(path: Path, e: Exception) -> AgentFileError:
    return AgentFileError(f"{path}: unreadable agents file ({type(e).__name__}: {_clip(e, 200)})")


def read_env_agents(path: str | Path) -> EnvAgents:
    """The agents ``write_env_agents`` wrote, or :class:`AgentFileError` naming the file; whether
    sizes, specs and weights agree ``pcpg_dist.reporting.onnx_export.check_cells`` checks."""
    path = Path(path).with_suffix("")
    json_path, npz_path = path.with_suffix(".json"), path.with_suffix(".npz")
    try:
        meta = json.loads(json_path.read_text())
        specs = tuple(CellInfo(**s) for s in meta["specs"])
        sizes = tuple(meta["sizes"])
        env, activation = meta["env"], meta["activation"]
    except _UNREADABLE as e:
        raise _unreadable(json_path, e) from None
    try:
        with np.load(npz_path, allow_pickle=False) as z:  # a pickled array is refused, never run
            arrays = {n: z[n] for n in z.files}
        params = {f"{w}{i}": arrays[f"{w}{i}"] for i in range(len(sizes) - 1) for w in "Wb"}
        mean, std = arrays["mean"], arrays["std"]
    except _UNREADABLE as e:
        raise _unreadable(npz_path, e) from None
    return EnvAgents(env, specs, sizes, activation, params, mean, std)


def read_all(folder: str | Path) -> dict[str, EnvAgents]:
    return {e.env: e for e in (read_env_agents(p) for p in sorted(Path(folder).glob("*.npz")))}


def load(model_uri: str, tracking_uri: str | None = None):
    """``mlflow.pyfunc.load_model`` without download bars or MLflow chatter, e.g.
    ``load(f"runs:/{run_id}/agents", "sqlite:///mlflow.db")``; never while serving (imports pcpg)."""
    from pcpg_dist.tracking.mlflow_quiet import quiet_logging

    with quiet_logging():
        if tracking_uri:
            mlflow.set_tracking_uri(tracking_uri)
        return mlflow.pyfunc.load_model(model_uri)


# ---------------------------------------------------------------------- request checks
def _missing(v) -> bool:
    return v is None or (isinstance(v, float) and v != v)


def _number(v) -> float:
    """``v`` as a float; NaN for anything but a plain number (None, bools, strings, lists)."""
    if isinstance(v, bool | np.bool_) or not isinstance(v, int | float | np.integer | np.floating):
        return float("nan")
    return float(v)


def _floats(df: pd.DataFrame, cols: list[str], rows: np.ndarray) -> np.ndarray:
    """(rows, cols) float64; NaN where a value is missing or not a number."""
    block, types = df[cols].iloc[rows], pd.api.types
    if all(types.is_numeric_dtype(t) and not types.is_bool_dtype(t) for t in block.dtypes):
        return block.to_numpy(np.float64)
    out = np.array([[_number(v) for v in block[c]] for c in cols], np.float64)
    return out.T.reshape(len(rows), len(cols))


def _integers(df: pd.DataFrame, col: str, rows: np.ndarray, optional: bool) -> np.ndarray:
    """Whole numbers of ``col`` at ``rows``; ``_NO_SEED`` where optional and missing."""
    if col in df and pd.api.types.is_integer_dtype(df[col].dtype):
        return df[col].to_numpy(np.int64)[rows]
    values = df[col].to_numpy(object)[rows] if col in df else np.full(len(rows), None, object)
    out = np.empty(len(rows), np.int64)
    for j, v in enumerate(values):
        if optional and _missing(v):
            out[j] = _NO_SEED
            continue
        x = _number(v)
        if not (np.isfinite(x) and x == int(x) and abs(x) < 2**53):
            raise AgentRequestError(
                f"row {rows[j]}: column {col!r} must be a whole number, got {_show(v)}"
            )
        out[j] = int(x)
    return out


def _valid_rows(df: pd.DataFrame, rows: np.ndarray, env: str, n_actions: int) -> np.ndarray:
    if "valid" not in df:
        return np.ones((len(rows), n_actions), bool)
    values = df["valid"].to_numpy(object)[rows]
    if len(values) and all(isinstance(v, list | tuple | np.ndarray) for v in values):
        try:
            block = np.array(list(values))  # the common case, checked in one go
        except ValueError:  # lists of different lengths: found row by row below
            block = np.zeros(0)
        if block.dtype == bool and block.shape == (len(rows), n_actions) and block.any(1).all():
            return block
    out = np.ones((len(rows), n_actions), bool)
    what = f"a list of {n_actions} booleans (true/false) for env {env!r}, or null for all valid"
    for j, v in enumerate(values):
        must = f"row {rows[j]}: column 'valid' must be {what};"
        if _missing(v):
            continue
        if not isinstance(v, list | tuple | np.ndarray) or getattr(v, "ndim", 1) == 0:
            raise AgentRequestError(f"{must} got {type(v).__name__} {_show(v)}")
        if len(v) != n_actions:
            raise AgentRequestError(f"{must} got a list of {len(v)}")
        # item by item: nested lists (ragged, deeper than NumPy's 64 dimensions) are bad requests
        bad = next((i for i, x in enumerate(v) if not isinstance(x, bool | np.bool_)), None)
        if bad is not None:
            raise AgentRequestError(f"{must} item {bad} is {_show(v[bad])}")
        out[j] = np.asarray(v, bool)
        if not out[j].any():
            raise AgentRequestError(
                f"row {rows[j]}: column 'valid' has no true item; at least one action must be valid"
            )
    return out


def _states(df: pd.DataFrame, rows: np.ndarray, env: str, d: int) -> np.ndarray:
    has = f"env {env!r} has {d} state features s0..s{d - 1}"
    for j in range(d):
        if f"s{j}" not in df:
            raise AgentRequestError(f"row {rows[0]}: column 's{j}' is missing; {has}")
    states = _floats(df, [f"s{j}" for j in range(d)], rows)
    bad = ~np.isfinite(states)
    if bad.any():
        r, j = np.argwhere(bad)[0]
        raise AgentRequestError(
            f"row {rows[r]}: column 's{j}' must be a finite number, got "
            f"{_show(df[f's{j}'].iloc[rows[r]])} ({has})"
        )
    digits = [c[1:] for c in df.columns if c.startswith("s") and c[1:].isdigit()]
    for c in (f"s{n}" for n in digits if len(n.lstrip("0")) > 6 or int(n) >= d):
        set_ = ~df[c].iloc[rows].isna().to_numpy()
        if set_.any():
            raise AgentRequestError(f"row {rows[set_.argmax()]}: column {_show(c)} is set; {has}")
    return states


# ---------------------------------------------------------------------- the model
class PcpgAgents(mlflow.pyfunc.PythonModel):
    def load_context(self, context) -> None:
        self.agents = read_all(context.artifacts["agents"])

    def _envs(self, df: pd.DataFrame) -> np.ndarray:
        names = sorted(self.agents)
        env = df["env"].to_numpy(object) if "env" in df else np.full(len(df), None, object)
        missing = np.array([_missing(v) for v in env], bool)
        if missing.any():
            if len(names) != 1:
                raise AgentRequestError(
                    f"row {int(np.argmax(missing))}: column 'env' is missing; this "
                    f"model has environments {_names(names)}: name one per row"
                )
            env = np.where(missing, names[0], env)
        for i, v in enumerate(env):
            if not isinstance(v, str) or v not in self.agents:
                raise AgentRequestError(
                    f"row {i}: env {_show(v)} is not in this model; environments: {_names(names)}"
                )
        return env

    def predict(self, context, model_input: pd.DataFrame, params=None) -> np.ndarray:
        try:
            df = pd.DataFrame(model_input).reset_index(drop=True)
        except (TypeError, ValueError) as e:
            raise AgentRequestError(f"the request must be a table of rows ({e})") from None
        try:
            return self._predict(df)
        except AgentRequestError:
            raise
        except RecursionError:  # a value nested deeper than Python recurses
            raise AgentRequestError(_TOO_DEEP) from None
        except Exception as e:  # a bug, not a bad request: HTTP 500, one line; the log has it
            _log.exception("pcpg agents model failed")
            raise OneLineError(
                f"internal error of the pcpg agents model ({type(e).__name__}: {e}); "
                f"the server log has the traceback",
                error_code=INTERNAL_ERROR,
            ) from None

    def _predict(self, df: pd.DataFrame) -> np.ndarray:
        for col in ("style", "p"):
            if col not in df:
                raise AgentRequestError(
                    f"column {col!r} is missing; every row needs style (cluster "
                    f"index, {NC_STYLE} = No Clustering) and p (skill level)"
                )
        out = np.empty(len(df), np.int64)
        envs = self._envs(df)
        for env in dict.fromkeys(envs):  # each environment, then each cell: one batched pass
            agents = self.agents[env]
            rows = np.nonzero(envs == env)[0]
            style = _integers(df, "style", rows, optional=False)
            seed = _integers(df, "seed", rows, optional=True)
            p = _floats(df, ["p"], rows)[:, 0]
            if not np.isfinite(p).all():
                r = int(np.argmax(~np.isfinite(p)))
                raise AgentRequestError(
                    f"row {rows[r]}: column 'p' must be a number, got "
                    f"{_show(df['p'].iloc[rows[r]])}"
                )
            combos = pd.MultiIndex.from_arrays([style, p, seed])
            codes, uniques = pd.factorize(combos)
            cell = np.empty(len(rows), np.int64)
            for j, (s, p_j, sd) in enumerate(uniques):  # each distinct (style, p, seed) once
                first = rows[int(np.argmax(codes == j))]
                cell[codes == j] = agents.cell_of(
                    int(first), int(s), float(p_j), None if sd == _NO_SEED else int(sd)
                )
            states = _states(df, rows, env, agents.state_dim)
            valid = _valid_rows(df, rows, env, agents.n_actions)
            for c in np.unique(cell):
                sel = cell == c
                out[rows[sel]] = agents.predict(states[sel], valid[sel], int(c))
        return out


_TOO_DEEP = "the request is nested too deeply to read; 'valid' is one flat list of booleans per row"


def _bound_request_parsing() -> None:
    """MLflow 3.17's scoring server parses the body in ``scoring_server._parse_json_data`` before
    predict: JSON nested past Python's recursion limit raised RecursionError in its ``json.loads``
    (HTTP 500), its 400s (not JSON, a value its schema cannot convert) echo the body whole. Wrapped:
    a short one-line 400. The server imports that module first; elsewhere nothing is wrapped."""
    server = sys.modules.get("mlflow.pyfunc.scoring_server")
    parse = getattr(server, "_parse_json_data", None)
    if parse is None or getattr(parse, "pcpg_bounded", False):
        return

    def bounded(*args, **kwargs):
        try:
            return parse(*args, **kwargs)
        except RecursionError:
            raise AgentRequestError(_TOO_DEEP) from None
        except MlflowException as e:
            e.message = _clip(e.message)  # its type and error code (400) stay
            raise

    bounded.pcpg_bounded = True
    server._parse_json_data = bounded


_bound_request_parsing()
mlflow.models.set_model(PcpgAgents())
