"""The trained agents as ONNX: one model per environment, for game engines and other runtimes.

``agents_<env>.onnx`` holds every cell of the environment as stacked weights; a batch row picks
its cell by index, so one session serves any mix of styles, skill levels and seeds:

- inputs: ``state`` float32 (B, d), ``valid`` bool (B, n_actions), ``cell`` int64 (B,);
- outputs: ``action`` int64 (B,), the greedy valid action, ties to the lowest index (exactly
  :meth:`pcpg_dist.stages.bc.TrainedCells.predict`), or -1 for a row with no valid action; ``logits``
  float32 (B, n_actions), -inf where the action is invalid.

``agents_<env>.json`` beside it (also in the model's ``metadata_props``) lists each cell index with
its key, kind, style k, p, seed and c. The graph is built with ``onnx.helper`` from plain
operators (Gather, MatMul, Add, Tanh/Relu, Where, ArgMax; opset 13), so it loads in any ONNX
runtime and the bytes depend on the weights alone.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from pcpg_dist.common.errors import DataError

OPSET = (
    13  # Gather, MatMul, Where, ArgMax(select_last_index): all there; old enough for most runtimes
)
IR_VERSION = 7  # the IR of opset 13, so older runtimes read the file too
FORMAT = 1


# --------------------------------------------------------------------------- the graph
def cell_table(cells) -> list[dict]:
    """One entry per cell index: what a caller needs to pick a cell (style k, p, seed)."""
    return [{"index": i, **asdict(s)} for i, s in enumerate(cells.specs)]


def sidecar(env: str, cells) -> dict:
    """The JSON written beside ``agents_<env>.onnx`` (the same table is in its metadata)."""
    pcpg = [s for s in cells.specs if s.kind == "pcpg"]
    return {
        "format": FORMAT,
        "env": env,
        "model": f"agents_{env}.onnx",
        "state_dim": cells.state_dim,
        "n_actions": cells.n_actions,
        "activation": cells.activation,
        "sizes": list(cells.sizes),
        "inputs": {
            "state": f"float32 (B, {cells.state_dim})",
            "valid": f"bool (B, {cells.n_actions}), true = action allowed",
            "cell": "int64 (B,), an index into cells",
        },
        "outputs": {
            "action": "int64 (B,): greedy valid action (ties to the lowest index), "
            "-1 where no action is valid",
            "logits": f"float32 (B, {cells.n_actions}), -inf where invalid",
        },
        "styles": sorted({s.k for s in pcpg}),
        "ps": sorted({s.p for s in pcpg}, reverse=True),
        "seeds": sorted({s.seed for s in cells.specs}),
        "cells": cell_table(cells),
    }


def _const(name: str, value: np.ndarray):
    """An initializer (a constant tensor of the graph)."""
    from onnx import numpy_helper

    return numpy_helper.from_array(np.ascontiguousarray(value), name)


def _graph_body(cells) -> tuple[list, list]:
    """The initializers and nodes: normalise the state by the row's cell, run its layers (each row
    meets its own cell's weights), mask invalid actions and take the greedy one."""
    from onnx import TensorProto, helper

    n_layers = len(cells.sizes) - 1
    inits = [
        _const("mean", cells.mean.astype(np.float32)),
        _const("std", cells.std.astype(np.float32)),
        _const("axis1", np.array([1], np.int64)),
        _const("neg_inf", np.array(-np.inf, np.float32)),
        _const("no_action", np.array(-1, np.int64)),
        _const("zero", np.array(0.0, np.float32)),
    ]
    nodes = [
        helper.make_node("Gather", ["mean", "cell"], ["m"], axis=0),
        helper.make_node("Gather", ["std", "cell"], ["s"], axis=0),
        helper.make_node("Sub", ["state", "m"], ["centred"]),
        helper.make_node("Div", ["centred", "s"], ["h0"]),
    ]
    h = "h0"
    for layer in range(n_layers):
        w, b = f"W{layer}", f"b{layer}"
        inits += [
            _const(w, cells.params[w].astype(np.float32)),
            _const(b, cells.params[b].astype(np.float32)),
        ]
        # (B, 1, in) @ (B, in, out): each row meets its own cell's weights
        nodes += [
            helper.make_node("Gather", [w, "cell"], [f"{w}_rows"], axis=0),
            helper.make_node("Gather", [b, "cell"], [f"{b}_rows"], axis=0),
            helper.make_node("Unsqueeze", [h, "axis1"], [f"{h}_row"]),
            helper.make_node("MatMul", [f"{h}_row", f"{w}_rows"], [f"z{layer}_row"]),
            helper.make_node("Squeeze", [f"z{layer}_row", "axis1"], [f"z{layer}"]),
        ]
        last = layer == n_layers - 1
        pre = "raw_logits" if last else f"pre{layer + 1}"
        nodes.append(helper.make_node("Add", [f"z{layer}", f"{b}_rows"], [pre]))
        if not last:
            h = f"h{layer + 1}"
            nodes.append(
                helper.make_node("Relu" if cells.activation == "relu" else "Tanh", [pre], [h])
            )
    nodes += [
        helper.make_node("Where", ["valid", "raw_logits", "neg_inf"], ["logits"]),
        helper.make_node("ArgMax", ["logits"], ["best"], axis=1, keepdims=0, select_last_index=0),
        helper.make_node("Cast", ["valid"], ["valid_f"], to=TensorProto.FLOAT),
        helper.make_node("ReduceMax", ["valid_f"], ["any_f"], axes=[1], keepdims=0),
        helper.make_node("Greater", ["any_f", "zero"], ["any_valid"]),
        helper.make_node("Where", ["any_valid", "best", "no_action"], ["action"]),
    ]
    return inits, nodes


def build_model(env: str, cells):
    """The ONNX model of one environment's ensemble (a :class:`~pcpg_dist.stages.bc.TrainedCells`)."""
    import onnx
    from onnx import TensorProto, helper

    from pcpg_dist.stages.bc import ACTIVATIONS

    d, n_actions = cells.state_dim, cells.n_actions
    if cells.activation not in ACTIVATIONS:
        raise DataError(
            f"env {env}: activation {cells.activation!r} has no ONNX export (relu, tanh)"
        )
    inits, nodes = _graph_body(cells)
    graph = helper.make_graph(
        nodes,
        f"pcpg_agents_{env}",
        inputs=[
            helper.make_tensor_value_info("state", TensorProto.FLOAT, ["batch", d]),
            helper.make_tensor_value_info("valid", TensorProto.BOOL, ["batch", n_actions]),
            helper.make_tensor_value_info("cell", TensorProto.INT64, ["batch"]),
        ],
        outputs=[
            helper.make_tensor_value_info("action", TensorProto.INT64, ["batch"]),
            helper.make_tensor_value_info("logits", TensorProto.FLOAT, ["batch", n_actions]),
        ],
        initializer=inits,
    )
    import pcpg_dist

    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="pcpg-dist",
        producer_version=pcpg_dist.__version__,
        doc_string=f"pcpg agents of env {env}: {len(cells.specs)} cells; "
        f"pick one per row with the cell input (see metadata pcpg.cells)",
    )
    model.ir_version = IR_VERSION
    meta = sidecar(env, cells)
    props = {
        "pcpg.format": str(FORMAT),
        "pcpg.env": env,
        "pcpg.state_dim": str(d),
        "pcpg.n_actions": str(n_actions),
        "pcpg.cells": json.dumps(meta["cells"]),
    }
    helper.set_model_props(model, props)
    onnx.checker.check_model(model, full_check=True)
    return model


def export_onnx(ensembles: dict, out: Path) -> list[Path]:
    """Write ``agents_<env>.onnx`` + ``agents_<env>.json`` per environment; returns the paths.

    Every env name is checked and every model built before the first file is written, so a bad
    env writes nothing, not even ``out``.
    """
    from pcpg_dist.common.files import atomic_write_bytes, confined

    out = Path(out)
    models = {}
    for env, cells in sorted(ensembles.items()):
        confined(out, env, "env")  # the env becomes a file name under out
        models[env] = build_model(env, cells)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for env, model in models.items():
        onnx_path, json_path = out / f"agents_{env}.onnx", out / f"agents_{env}.json"
        atomic_write_bytes(onnx_path, model.SerializeToString(deterministic=True))
        atomic_write_bytes(
            json_path, (json.dumps(sidecar(env, ensembles[env]), indent=1) + "\n").encode()
        )
        written += [onnx_path, json_path]
    return written
