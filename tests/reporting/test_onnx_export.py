"""ONNX export: onnxruntime acts exactly like TrainedCells.predict, for every cell; `pcpg export onnx`."""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from bc_toy import make_dataset

from pcpg_dist.api.export import load_agents_folder
from pcpg_dist.cli import main
from pcpg_dist.common.errors import DataError
from pcpg_dist.config.stages import BCConfig
from pcpg_dist.dataset import Dataset
from pcpg_dist.domains.defaults import split_trajectories
from pcpg_dist.reporting.onnx_export import build_model, export_onnx
from pcpg_dist.stages.bc import TrainedCells, train_cells
from pcpg_dist.stages.ranking import RankConfig, plan_cells


def many_actions_dataset(
    n_actions: int = 300, d: int = 6, per_style: int = 30, seed: int = 0
) -> Dataset:
    """Two styles, each picking the valid action its own linear score likes best; ~30 % valid."""
    rng = np.random.default_rng(seed)
    prefs = rng.normal(size=(2, d, n_actions))
    trajs, styles, success = [], [], []
    for style in (0, 1):
        for _ in range(per_style):
            steps = int(rng.integers(5, 15))
            states = rng.normal(size=(steps + 1, d))
            valid = rng.random((steps + 1, n_actions)) < 0.3
            valid[np.arange(steps + 1), rng.integers(0, n_actions, steps + 1)] = True
            actions = np.argmax(np.where(valid[:-1], states[:-1] @ prefs[style], -np.inf), axis=1)
            trajs.append(
                {"states": states, "actions": actions, "valid": valid, "rewards": np.zeros(steps)}
            )
            styles.append(style)
            success.append(bool(rng.random() < 0.7))
    return Dataset.from_trajectories("toy", "many", n_actions, trajs, styles, success)


def train_toy(dataset: Dataset, activation: str, epochs: int = 150, seeds=(0, 1)) -> TrainedCells:
    """PCPG and No-Clustering cells at p = 1 and 0.5 (and the seeds given), briefly trained."""
    tr, _ = split_trajectories(dataset.n_trajectories, 0.2, 0)
    cells = plan_cells(dataset, dataset.styles, tr, RankConfig(ps=(1.0, 0.5)), seeds=list(seeds))
    return train_cells(cells, BCConfig(epochs=epochs, activation=activation, hidden_size=8))


@pytest.fixture(scope="module")
def grid():
    return make_dataset(40, seed=0)


@pytest.fixture(scope="module")
def many():
    return many_actions_dataset()


def _session(model: onnx.ModelProto) -> ort.InferenceSession:
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = opts.inter_op_num_threads = 1
    return ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])


def _random_batch(rng, n: int, cells: TrainedCells):
    """States on the data's scale (mean + std * N(0, 1)); random valid masks, at least one true."""
    n_actions = cells.n_actions
    states = (cells.mean[0] + cells.std[0] * rng.normal(size=(n, cells.state_dim))).astype(
        np.float32
    )
    valid = rng.random((n, n_actions)) < rng.uniform(0.05, 0.9)
    valid[np.arange(n), rng.integers(0, n_actions, n)] = True  # every row can act
    return states, valid


@pytest.mark.parametrize(
    ("case", "activation"), [("grid", "tanh"), ("grid", "relu"), ("many", "tanh"), ("many", "relu")]
)
def test_onnx_acts_like_trained_cells_for_every_cell(case, activation, request, rng):
    dataset = request.getfixturevalue(case)
    cells = train_toy(dataset, activation)
    session = _session(build_model("E", cells))
    n = 1000
    states, valid = _random_batch(rng, n, cells)
    for i in range(len(cells.specs)):
        action, logits = session.run(
            ["action", "logits"], {"state": states, "valid": valid, "cell": np.full(n, i, np.int64)}
        )
        want = cells.logits(states, i, valid)
        # float32 sums in another order: equal to 1e-5 of the batch's largest logit (~100 ulps);
        # -inf exactly where invalid
        scale = max(1.0, float(np.abs(want[np.isfinite(want)]).max()))
        np.testing.assert_allclose(logits, want, rtol=1e-5, atol=1e-5 * scale)
        np.testing.assert_array_equal(action, cells.predict(states, valid, i))
    # one batch mixing every cell gives each row its own cell's action
    cell = rng.integers(0, len(cells.specs), n)
    action = session.run(["action"], {"state": states, "valid": valid, "cell": cell})[0]
    want = np.array(
        [cells.predict(states[r : r + 1], valid[r : r + 1], int(cell[r]))[0] for r in range(n)]
    )
    np.testing.assert_array_equal(action, want)


def test_ties_go_to_the_lowest_index_and_no_valid_action_gives_minus_one(grid):
    cells = train_toy(grid, "tanh", epochs=0)
    zeroed = {n: np.zeros_like(v) for n, v in cells.params.items()}  # every logit 0: all tied
    flat = TrainedCells(
        cells.specs, cells.sizes, cells.activation, zeroed, cells.mean, cells.std, cells.final_loss
    )
    session = _session(build_model("E", flat))
    valid = np.array([[False, True, True, True], [False, False, False, True], [False] * 4])
    action = session.run(
        ["action"],
        {"state": np.zeros((3, 4), np.float32), "valid": valid, "cell": np.zeros(3, np.int64)},
    )[0]
    assert action.tolist() == [1, 3, -1]


def test_metadata_sidecar_and_deterministic_bytes(grid, tmp_path):
    cells = train_toy(grid, "tanh", epochs=20)
    paths = export_onnx({"E1": cells}, tmp_path / "a")
    again = export_onnx({"E1": cells}, tmp_path / "b")
    assert [p.name for p in paths] == ["agents_E1.onnx", "agents_E1.json"]
    for p, q in zip(paths, again, strict=True):
        assert p.read_bytes() == q.read_bytes()
    model = onnx.load(paths[0])
    onnx.checker.check_model(model, full_check=True)
    assert model.opset_import[0].version == 13
    props = {p.key: p.value for p in model.metadata_props}
    side = json.loads(paths[1].read_text())
    assert json.loads(props["pcpg.cells"]) == side["cells"]
    assert (side["state_dim"], side["n_actions"], props["pcpg.n_actions"]) == (4, 4, "4")
    assert side["styles"] == [0, 1] and side["ps"] == [1.0, 0.5] and side["seeds"] == [0, 1]
    # a game engine picks "style 1 at p = 0.5, seed 0" from the table
    pick = [
        c["index"]
        for c in side["cells"]
        if (c["kind"], c["k"], c["p"], c["seed"]) == ("pcpg", 1, 0.5, 0)
    ]
    assert (
        len(pick) == 1 and side["cells"][pick[0]]["key"] == cells.specs[pick[0]].key == "k1-p0.5-s0"
    )
    kinds = {c["kind"] for c in side["cells"]}
    assert kinds == {"pcpg", "nc"}


def _run_folder(tmp_path, grid, many) -> tuple:
    """``RUN/agents/<env>/groupNNN.pt|.json`` as `pcpg run` leaves it; E2's cells in two groups."""
    e1, e2 = train_toy(grid, "tanh", epochs=30), train_toy(many, "relu", epochs=30, seeds=(0,))
    run = tmp_path / "runs" / "demo"
    e1.save(run / "agents" / "E1" / "group000")
    half = len(e2.specs) // 2
    e2.select(e2.keys[:half]).save(run / "agents" / "E2" / "group000")
    e2.select(e2.keys[half:]).save(run / "agents" / "E2" / "group001")
    return run, e1, e2


def test_cli_exports_a_run_folder(tmp_path, grid, many, capsys, rng):
    run, e1, e2 = _run_folder(tmp_path, grid, many)
    out = tmp_path / "onnx"
    assert main(["export", "onnx", str(run), "--out", str(out)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith(f"wrote {out / 'agents_E1.onnx'}") and len(printed) == 4
    assert sorted(p.name for p in out.iterdir()) == [
        "agents_E1.json",
        "agents_E1.onnx",
        "agents_E2.json",
        "agents_E2.onnx",
    ]
    assert load_agents_folder(run / "agents")["E2"].keys == e2.keys
    side = json.loads((out / "agents_E2.json").read_text())
    assert side["n_actions"] == 300 and [c["key"] for c in side["cells"]] == e2.keys
    session = _session(onnx.load(out / "agents_E2.onnx"))
    states, valid = _random_batch(rng, 200, e2)
    for i in (0, len(e2.specs) - 1):
        got = session.run(
            ["action"], {"state": states, "valid": valid, "cell": np.full(200, i, np.int64)}
        )[0]
        np.testing.assert_array_equal(got, e2.predict(states, valid, i))


def test_a_run_whose_agents_do_not_match_its_summary_is_refused(tmp_path, grid, many, capsys):
    """An environment's agents deleted from a run folder (or agents of one it does not report)
    used to export the rest with exit 0, as if it were the whole run."""
    import shutil

    run, _, _ = _run_folder(tmp_path, grid, many)
    (run / "summary").mkdir()
    (run / "summary" / "run.json").write_text("{}")
    for env in ("E1", "E2"):
        (run / "summary" / env).mkdir()
        (run / "summary" / env / "metrics.json").write_text("{}")
    assert main(["export", "onnx", str(run), "--out", str(tmp_path / "ok")]) == 0
    capsys.readouterr()
    shutil.rmtree(run / "agents" / "E2")
    assert main(["export", "onnx", str(run), "--out", str(tmp_path / "o1")]) == 2
    err = capsys.readouterr().err.strip()
    assert "no agents for E2" in err and "\n" not in err and not (tmp_path / "o1").exists()
    shutil.copytree(run / "agents" / "E1", run / "agents" / "E9")
    assert main(["export", "onnx", str(run), "--out", str(tmp_path / "o2")]) == 2
    assert "agents for E9, which it does not report" in capsys.readouterr().err


@pytest.mark.parametrize("target", ["missing", "empty"])
def test_cli_bad_run_is_one_line_exit_2(tmp_path, target):
    (tmp_path / "empty").mkdir()
    cmd = [
        sys.executable,
        "-m",
        "pcpg_dist.cli",
        "export",
        "onnx",
        str(tmp_path / target),
        "--out",
        str(tmp_path / "out"),
        "--tracking-uri",
        f"sqlite:///{tmp_path / 'no.db'}",
    ]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert (
        len(lines) == 1
        and lines[0].startswith("pcpg: error: ")
        and str(tmp_path / target) in lines[0]
    )
    assert not (tmp_path / "out").exists() and not (tmp_path / "no.db").exists()


def _files(root) -> set:
    return {p for p in root.rglob("*") if p.is_file()}


def _set(key, value):
    return lambda m: m.__setitem__(key, value)


# (layout, how the agents' JSON is changed, what the one error line says after the file's name)
HOSTILE_AGENTS = {
    "env escapes": (
        "npz",
        _set("env", "x/../../escaped"),
        "env 'x/../../escaped' is not a plain name",
    ),
    "env absolute": (
        "npz",
        _set("env", "/tmp/abs_escaped"),
        "env '/tmp/abs_escaped' is not a plain name",
    ),
    "env renamed": (
        "npz",
        _set("env", "E2"),
        "env 'E2' does not match the file's name (expected 'E1'",
    ),
    "not json": ("npz", "{not json", "unreadable agents file (JSONDecodeError"),
    "no activation": (
        "npz",
        lambda m: m.pop("activation"),
        "unreadable agents file (KeyError: 'activation')",
    ),
    "p zero": (
        "npz",
        lambda m: m["specs"][1].__setitem__("p", 0),
        "specs[1]: p 0 must be a number in (0, 1]",
    ),
    "too few sizes": (
        "pt",
        _set("sizes", [4, 8, 4]),
        "W1 has shape (12, 8, 8) (float32), but sizes [4, 8, 4] need (12, 8, 4)",
    ),
    "wider sizes": (
        "pt",
        _set("sizes", [4, 7, 7, 7, 4]),
        "W0 has shape (12, 4, 8) (float32), but sizes",
    ),
    "sizes string": (
        "pt",
        _set("sizes", "abc"),
        "sizes ['a', 'b', 'c'] must be a list of at least two positive",
    ),
    "no specs": ("pt", _set("specs", []), "specs is empty"),
    "3 specs": (
        "pt",
        lambda m: m.__setitem__("specs", m["specs"][:3]),
        "3 specs for 12 weight sets",
    ),
    "p string": (
        "pt",
        lambda m: m["specs"][0].__setitem__("p", "x"),
        "specs[0]: p 'x' must be a number in (0, 1]",
    ),
    "activation": (
        "pt",
        _set("activation", "sigmoid"),
        "activation 'sigmoid' is not one of relu, tanh",
    ),
}


@pytest.mark.parametrize("case", HOSTILE_AGENTS)
def test_hostile_agent_files_are_one_line_and_write_nothing(case, grid, tmp_path, capsys):
    from pcpg_dist.tracking import agent_packaging

    layout, edit, says = HOSTILE_AGENTS[case]
    cells = train_toy(grid, "tanh", epochs=0)  # 12 cells, sizes (4, 8, 8, 8, 4)
    agents = tmp_path / "run" / "agents"
    if layout == "npz":  # the MLflow agents model's artifacts
        agent_packaging.write_env_agents(agents / "E1", "E1", cells)
        meta_file = agents / "E1.json"
    else:  # pcpg run's output
        cells.save(agents / "E1" / "group000")
        meta_file = agents / "E1" / "group000.json"
    if isinstance(edit, str):
        meta_file.write_text(edit)
    else:
        meta = json.loads(meta_file.read_text())
        edit(meta)
        meta_file.write_text(json.dumps(meta))
    before = _files(tmp_path)
    out = tmp_path / "deep" / "out"  # where "x/../../escaped" would land, were it used
    assert main(["export", "onnx", str(tmp_path / "run"), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"pcpg: error: {meta_file}: {says}"), err
    assert _files(tmp_path) == before and not out.exists() and not (tmp_path / "deep").exists()
    assert not pathlib.Path("/tmp/abs_escaped").exists()


def test_export_onnx_refuses_an_env_that_is_not_a_plain_name_before_writing(grid, tmp_path):
    cells = train_toy(grid, "tanh", epochs=0)
    with pytest.raises(DataError, match=r"env '\.\./E2' is not a plain name"):
        export_onnx({"E1": cells, "../E2": cells}, tmp_path / "out")
    assert not (tmp_path / "out").exists() and _files(tmp_path) == set()
