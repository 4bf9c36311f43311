"""The `agents` pyfunc model: logged like a sweep logs it, loaded, served over REST, exported to ONNX.

The REST test posts the request example of docs/agents.md verbatim, so the documentation cannot
drift from what the model accepts.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from bc_toy import make_dataset
from reporting.test_onnx_export import many_actions_dataset, train_toy

from pcpg_dist.tracking.runs import open_experiment
from pcpg_dist.tracking.trackers import Tracker

DOC = Path(__file__).resolve().parents[2] / "docs" / "agents.md"


def doc_request() -> dict:
    """The JSON block after ``<!-- request-example -->`` in docs/agents.md."""
    text = DOC.read_text()
    block = re.search(r"<!-- request-example -->\s*```json\n(.*?)```", text, re.S)
    return json.loads(block.group(1))


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """Two environments as a sweep leaves them: E1 (4 features, 4 actions, tanh, seeds 0 and 1),
    E2 (6 features, 300 actions, relu, seed 0), logged into a fresh SQLite store."""
    root = tmp_path_factory.mktemp("agents")
    e1 = train_toy(make_dataset(40, seed=0), "tanh", epochs=60)
    e2 = train_toy(many_actions_dataset(), "relu", epochs=60, seeds=(0,))
    e1.save(root / "run" / "agents" / "E1" / "group000")
    e2.save(root / "run" / "agents" / "E2" / "group000")
    uri = f"sqlite:///{root / 'mlflow.db'}"
    uri, client, exp = open_experiment("agents-test", uri)
    run_id = client.create_run(exp, tags={"pcpg.role": "parent"}).info.run_id
    return {
        "root": root,
        "uri": uri,
        "run_id": run_id,
        "E1": e1,
        "E2": e2,
        "tracker": Tracker(uri, exp, run_id, "test"),
    }


@pytest.fixture(scope="module")
def model(logged):
    import mlflow

    records = []

    class Grab(logging.Handler):
        def emit(self, record):
            records.append(record.getMessage())

    handler = Grab(level=logging.INFO)
    logging.getLogger("mlflow").addHandler(handler)
    try:
        logged["tracker"]._log_agents(logged["root"] / "run" / "agents")
    finally:
        logging.getLogger("mlflow").removeHandler(handler)
    logged["log_messages"] = records
    mlflow.set_tracking_uri(logged["uri"])
    return mlflow.pyfunc.load_model(f"runs:/{logged['run_id']}/agents")


def _expected(logged, df: pd.DataFrame) -> np.ndarray:
    """TrainedCells.predict row by row, picking the cell by (style, p, seed) as documented."""
    out = []
    for row in df.to_dict("records"):
        cells = logged[row["env"]]
        kind = "nc" if row["style"] == -1 else "pcpg"
        seed = row.get("seed")
        seed = None if seed is None or seed != seed else int(seed)
        matches = [
            i
            for i, s in enumerate(cells.specs)
            if s.kind == kind
            and (kind == "nc" or s.k == row["style"])
            and s.p == row["p"]
            and (seed is None or s.seed == seed)
        ]
        i = min(matches, key=lambda i: cells.specs[i].seed)
        state = np.array([[row[f"s{j}"] for j in range(cells.state_dim)]], np.float32)
        valid = row.get("valid")
        valid = (
            np.ones((1, cells.n_actions), bool)
            if not isinstance(valid, list)
            else np.array([valid])
        )
        out.append(int(cells.predict(state, valid, i)[0]))
    return np.array(out)


def test_logged_with_pinned_requirements_signature_and_no_inference(logged, model):
    from mlflow.artifacts import download_artifacts

    local = Path(
        download_artifacts(
            artifact_uri=f"runs:/{logged['run_id']}/agents",
            dst_path=str(logged["root"] / "dl"),
            tracking_uri=logged["uri"],
        )
    )
    reqs = (local / "requirements.txt").read_text().split()
    assert [r.split("==")[0] for r in reqs] == ["mlflow", "numpy", "pandas"]
    assert all(re.fullmatch(r"[a-z]+==\d+\.\d+\.\d+\S*", r) for r in reqs)
    assert not (local / "uv.lock").exists()  # the project's lock (torch, ray, ...) stays out
    assert sorted(p.name for p in (local / "artifacts" / "agents").iterdir()) == [
        "E1.json",
        "E1.npz",
        "E2.json",
        "E2.npz",
    ]
    messages = " | ".join(logged["log_messages"])
    assert "infer" not in messages.lower() and "pip version" not in messages, messages
    sig = model.metadata.get_input_schema()
    assert sig.input_names() == ["env", "style", "p", "seed", "valid", *(f"s{j}" for j in range(6))]
    assert not any(c.required for c in sig.inputs)
    # the input example uses a trained style and p, and MLflow stored it ready for serving
    example = json.loads((local / "serving_input_example.json").read_text())
    frame = pd.DataFrame(**example["dataframe_split"])
    assert list(frame["env"]) == ["E1", "E2"] and list(model.predict(frame)) == list(
        _expected(logged, frame)
    )


def test_predict_matches_trained_cells_vectorised(logged, model, rng):
    """A batch mixing both environments, every PCPG/NC cell and random valid masks."""
    rows = []
    for env in ("E1", "E2"):
        cells = logged[env]
        for spec in (s for s in cells.specs if s.kind in ("pcpg", "nc")):
            for _ in range(25):
                state = cells.mean[0] + cells.std[0] * rng.normal(size=cells.state_dim)
                valid = rng.random(cells.n_actions) < 0.4
                valid[rng.integers(cells.n_actions)] = True
                row = {
                    "env": env,
                    "style": spec.k if spec.kind == "pcpg" else -1,
                    "p": spec.p,
                    "seed": spec.seed,
                    "valid": valid.tolist(),
                }
                row.update({f"s{j}": float(state[j]) for j in range(cells.state_dim)})
                rows.append(row)
    df = pd.DataFrame(rows).sample(frac=1.0, random_state=0).reset_index(drop=True)
    got = model.predict(df)
    np.testing.assert_array_equal(got, _expected(logged, df))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"p": 0.25}, "row 0: env 'E1': p=0.25 is not trained for style 1; trained p: 1, 0.5"),
        (
            {"style": 7},
            "row 0: env 'E1': style 7 is not trained; trained styles: 0, 1 (and -1 = No Clustering)",
        ),
        (
            {"seed": 5},
            "row 0: env 'E1': seed 5 is not trained for style 1 at p=0.5; trained seeds: 0, 1",
        ),
        (
            {"env": None},
            "row 0: column 'env' is missing; this model has environments E1, E2: name one per row",
        ),
        ({"env": "E9"}, "row 0: env 'E9' is not in this model; environments: E1, E2"),
        (
            {"valid": [True, float("nan"), True, True]},
            "row 0: column 'valid' must be a list of 4 booleans "
            "(true/false) for env 'E1', or null for all valid; item 1 is nan",
        ),
        (
            {"valid": [True, True]},
            "row 0: column 'valid' must be a list of 4 booleans (true/false) for env "
            "'E1', or null for all valid; got a list of 2",
        ),
        (
            {"valid": 6},
            "row 0: column 'valid' must be a list of 4 booleans (true/false) for env 'E1', or "
            "null for all valid; got int 6",
        ),
        (
            {"valid": [[True]] * 4},
            "row 0: column 'valid' must be a list of 4 booleans (true/false) for env "
            "'E1', or null for all valid; item 0 is [True]",
        ),
        (
            {"valid": [False] * 4},
            "row 0: column 'valid' has no true item; at least one action must be valid",
        ),
        ({"style": 1.5}, "row 0: column 'style' must be a whole number, got 1.5"),
        (
            {"s3": float("nan")},
            "row 0: column 's3' must be a finite number, got nan (env 'E1' has 4 state "
            "features s0..s3)",
        ),
    ],
)
def test_bad_rows_get_one_line_errors(model, change, message):
    from mlflow.exceptions import MlflowException

    row = {**doc_request()["dataframe_records"][0], **change}
    with pytest.raises(MlflowException) as err:  # the model file's own AgentRequestError class
        model.predict(pd.DataFrame([row]))
    assert type(err.value).__name__ == "AgentRequestError"
    assert err.value.error_code == "INVALID_PARAMETER_VALUE" and err.value.message == message


def test_error_names_the_row_in_a_mixed_batch(logged, model):
    from mlflow.exceptions import MlflowException

    good = doc_request()["dataframe_records"]
    e2 = {"env": "E2", "style": 0, "p": 0.5, **{f"s{j}": 0.0 for j in range(6)}}
    df = pd.DataFrame([*good, e2, {**good[0], "p": 0.1}])
    with pytest.raises(
        MlflowException,
        match=r"^row 4: env 'E1': p=0.1 is not trained for style 1; "
        r"trained p: 1, 0.5$",
    ):
        model.predict(df)
    assert model.predict(df.iloc[:4]).tolist() == _expected(logged, df.iloc[:4]).tolist()


def test_export_onnx_from_the_mlflow_run(logged, model, tmp_path, capsys):
    import onnxruntime as ort

    from pcpg_dist.cli import main

    out = tmp_path / "onnx"
    assert (
        main(
            ["export", "onnx", logged["run_id"], "--out", str(out), "--tracking-uri", logged["uri"]]
        )
        == 0
    )
    assert "agents_E2.onnx" in capsys.readouterr().out
    cells = logged["E2"]
    session = ort.InferenceSession(str(out / "agents_E2.onnx"), providers=["CPUExecutionProvider"])
    states = (cells.mean[0] + cells.std[0] * np.random.default_rng(1).normal(size=(50, 6))).astype(
        np.float32
    )
    valid = np.ones((50, 300), bool)
    for i in range(len(cells.specs)):
        got = session.run(
            ["action"], {"state": states, "valid": valid, "cell": np.full(50, i, np.int64)}
        )[0]
        np.testing.assert_array_equal(got, cells.predict(states, valid, i))
    # the experiment name resolves to its latest parent run: the same files
    again = tmp_path / "again"
    assert (
        main(
            ["export", "onnx", "agents-test", "--out", str(again), "--tracking-uri", logged["uri"]]
        )
        == 0
    )
    assert (again / "agents_E1.onnx").read_bytes() == (out / "agents_E1.onnx").read_bytes()
    capsys.readouterr()
    # a run without agents (a sweep logged with tracking off, or still running): one line, exit 2
    from mlflow import MlflowClient

    client = MlflowClient(logged["uri"])
    bare = client.create_run(client.get_experiment_by_name("agents-test").experiment_id).info.run_id
    assert (
        main(
            [
                "export",
                "onnx",
                bare,
                "--out",
                str(tmp_path / "none"),
                "--tracking-uri",
                logged["uri"],
            ]
        )
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(
        f"pcpg: error: run {bare} at {logged['uri']} has no agents model"
    ), err


# ---------------------------------------------------------------------- REST
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _post(port: int, body: str) -> tuple[int, str]:
    req = urllib.request.Request(
        f"http://127.0.0.1:{port}/invocations",
        data=body.encode(),
        headers={"Content-Type": "application/json"},
    )
    try:
        with urllib.request.urlopen(req, timeout=30) as resp:
            return resp.status, resp.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode()


@pytest.mark.slow
def test_rest_server_answers_the_documented_request_and_one_line_errors(logged, model, tmp_path):
    port = _free_port()
    bin_dir = str(Path(sys.executable).parent)  # mlflow starts uvicorn from the PATH
    env = {
        **os.environ,
        "MLFLOW_TRACKING_URI": logged["uri"],
        "PATH": bin_dir + os.pathsep + os.environ["PATH"],
    }
    log = open(tmp_path / "server.log", "w")  # noqa: SIM115 - closed in finally
    server = subprocess.Popen(
        [
            str(Path(bin_dir) / "mlflow"),
            "models",
            "serve",
            "-m",
            f"runs:/{logged['run_id']}/agents",
            "--env-manager",
            "local",
            "-h",
            "127.0.0.1",
            "-p",
            str(port),
            "-w",
            "1",
        ],
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
        cwd=Path(__file__).resolve().parents[2],
        start_new_session=True,
    )  # its own process group: the uvicorn worker goes down with it
    try:
        deadline = time.monotonic() + 90
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/ping", timeout=2) as r:
                    if r.status == 200:
                        break
            except (urllib.error.URLError, OSError):
                pass
            if server.poll() is not None or time.monotonic() > deadline:
                pytest.fail(
                    f"server did not start: {(tmp_path / 'server.log').read_text()[-2000:]}"
                )
            time.sleep(0.5)

        request = doc_request()
        status, body = _post(port, json.dumps(request))
        assert status == 200, body
        want = _expected(logged, pd.DataFrame(request["dataframe_records"]))
        assert json.loads(body) == {"predictions": want.tolist()}

        row = request["dataframe_records"][0]
        bad = {
            "NaN in valid": ({**row, "valid": [False, True, float("nan"), False]}, "item 2 is nan"),
            "no env, two envs": (
                {k: v for k, v in row.items() if k != "env"},
                "column 'env' is missing",
            ),
            "untrained p": (
                {**row, "p": 0.25},
                "p=0.25 is not trained for style 1; trained p: 1, 0.5",
            ),
            "wrong valid length": ({**row, "valid": [True] * 5}, "got a list of 5"),
            "old bitmask": ({**row, "valid": 6}, "got int 6"),
            "missing feature": (
                {k: v for k, v in row.items() if k != "s3"},
                "column 's3' is missing",
            ),
            "fractional style": ({**row, "style": 1.5}, "must be a whole number, got 1.5"),
        }
        for what, (record, part) in bad.items():
            status, body = _post(port, json.dumps({"dataframe_records": [record]}))
            assert status == 400, (what, body)
            assert "\n" not in body.strip(), (what, body)
            answer = json.loads(body)
            assert answer["error_code"] == "INVALID_PARAMETER_VALUE", (what, answer)
            assert answer["message"].startswith("row 0: ") and part in answer["message"], (
                what,
                answer,
            )
            assert "\n" not in answer["message"], (what, answer)
            assert "stack_trace" not in answer and "Traceback" not in body, (what, answer)
        # a request MLflow itself rejects (no dataframe key): still one line, no traceback
        status, body = _post(port, json.dumps({"rows": [row]}))
        assert status == 400 and "\n" not in body.strip() and "Traceback" not in body, body
        # JSON nested 100,000 deep was HTTP 500 `Internal Server Error` (RecursionError in MLflow's
        # json.loads); a 1 MB env came back whole (a 1,000,171-byte 400)
        deep = "[" * 100_000 + "true" + "]" * 100_000
        for body, part in [
            (
                json.dumps({"dataframe_records": [{**row, "valid": None}]}).replace("null", deep),
                "deep",
            ),
            (json.dumps({"dataframe_records": [{**row, "env": "x" * 1_000_000}]}), "env 'xxxx"),
        ]:
            status, answer = _post(port, body)
            assert status == 400 and len(answer) < 1000 and "\n" not in answer.strip(), answer[:300]
            assert part in json.loads(answer)["message"], answer
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        try:
            server.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait()
        log.close()


# ---------------------------------------------------------------------- hostile requests
def _nested(depth: int):
    v = True
    for _ in range(depth):
        v = [v]
    return v


@pytest.mark.parametrize(
    ("change", "part"),
    [
        # deeper than NumPy's 64 dimensions, or ragged: these were HTTP 500 (an internal error)
        ({"valid": [_nested(70), True, True, True]}, "item 0 is [[[[[[[...]]]]]]]"),
        ({"valid": _nested(100_000)}, "got a list of 1"),
        ({"valid": [True, [True], True, True]}, "item 1 is [True]"),
        ({"valid": [True, "z" * 1_000_000, True, True]}, "item 1 is 'zzzz"),
        ({"env": "x" * 1_000_000}, "row 0: env 'xxxxxxxx"),
        ({"style": "7" * 1_000_000}, "must be a whole number, got '777777"),
    ],
)
def test_hostile_values_get_short_one_line_errors(model, change, part):
    """Every value a message shows is cut short (reprlib), and nesting deeper than NumPy's
    64 dimensions or Python's recursion limit is a bad request, not an internal error."""
    from mlflow.exceptions import MlflowException

    row = {**doc_request()["dataframe_records"][0], **change}
    with pytest.raises(MlflowException) as err:
        model.predict(pd.DataFrame([row]))
    assert type(err.value).__name__ == "AgentRequestError", err.value.message[:300]
    assert err.value.get_http_status_code() == 400
    message = err.value.message
    assert part in message and "\n" not in message and len(message) < 400, message[:1000]


async def _asgi_post(app, body: bytes) -> tuple[int, bytes]:
    """POST /invocations to an ASGI app in this process, as uvicorn would (no httpx here)."""
    incoming = [{"type": "http.request", "body": body, "more_body": False}]
    sent: list[dict] = []

    async def receive():
        return incoming.pop(0) if incoming else {"type": "http.disconnect"}

    async def send(message):
        sent.append(message)

    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": "POST",
        "scheme": "http",
        "path": "/invocations",
        "raw_path": b"/invocations",
        "query_string": b"",
        "root_path": "",
        "headers": [(b"content-type", b"application/json")],
        "client": ("127.0.0.1", 1),
        "server": ("127.0.0.1", 80),
    }
    with contextlib.suppress(Exception):  # Starlette re-raises after its 500, as under uvicorn
        await app(scope, receive, send)
    status = next(m["status"] for m in sent if m["type"] == "http.response.start")
    return status, b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")


def test_scoring_server_answers_hostile_requests_with_short_400s(logged, monkeypatch):
    """MLflow's own scoring app (what `mlflow models serve` runs), in process: JSON nested 100,000
    levels deep raised RecursionError in MLflow's json.loads (HTTP 500 `Internal Server Error`), and
    a 1 MB value came back whole in the 400 body."""
    import asyncio

    import mlflow
    from mlflow.pyfunc import scoring_server

    monkeypatch.delenv("MLFLOW_IS_IN_SERVING_ENVIRONMENT", raising=False)  # init() sets it
    mlflow.set_tracking_uri(logged["uri"])
    served = mlflow.pyfunc.load_model(f"runs:/{logged['run_id']}/agents")  # as the server loads it
    app = scoring_server.init(served)
    row = json.dumps(doc_request()["dataframe_records"][0])
    deep = "[" * 100_000 + "true" + "]" * 100_000
    cases = {
        "deep valid": (
            '{"dataframe_records": [' + row[:-1] + ', "valid": ' + deep + "}]}",
            "nested",
        ),
        "deep body": (deep, "nested"),
        "1 MB env": (
            json.dumps({"dataframe_records": [{**json.loads(row), "env": "x" * 1_000_000}]}),
            "row 0: env 'xxxx",
        ),
        "1 MB of bad JSON": ('{"dataframe_records": ' + "x" * 1_000_000, "valid JSON"),
        "1 MB state": (  # MLflow's own schema check converts s0..: its message echoed it whole
            json.dumps({"dataframe_records": [{**json.loads(row), "s3": "y" * 1_000_000}]}),
            "s3",
        ),
    }
    for what, (body, part) in cases.items():
        status, answer = asyncio.run(_asgi_post(app, body.encode()))
        assert status == 400, (what, status, answer[:300])
        assert len(answer) < 1000 and b"\n" not in answer.strip(), (what, answer[:1000])
        message = json.loads(answer)["message"]
        assert part in message, (what, message)
    status, answer = asyncio.run(_asgi_post(app, json.dumps(doc_request()).encode()))
    assert status == 200, answer
