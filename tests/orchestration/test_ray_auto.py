"""``RAY_ADDRESS=auto`` / ``--ray-address auto`` with no live cluster behind it: one line, at once.

Ray resolves ``auto`` to the address in ``ray_current_cluster`` (under ``$RAY_TMPDIR/ray``), the
latest `ray start` on the machine. When that cluster is gone, ``ray.init`` waited ~14 min on the
dead port, printing Ray's C++ warnings and no ``pcpg:`` line. No real Ray starts here: the temp
folder is this test's own, and ``ray.init`` is replaced by a stub that fails at once were it reached.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pcpg_dist.common.errors import ServiceError
from pcpg_dist.orchestration import ray_pool

ROOT = Path(__file__).resolve().parents[2]


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]  # closed again on leaving: nothing listens there


@pytest.fixture
def ray_tmp(tmp_path, monkeypatch):
    """Ray's temp folder for this test only; no Ray running on the machine is seen; ray.init is
    never reached (the stub fails at once, so the code before the fix failed instead of hanging)."""
    import ray
    from ray._private import services

    def no_init(*args, **kwargs):
        raise RuntimeError("ray.init was reached")

    monkeypatch.setenv("RAY_TMPDIR", str(tmp_path))
    monkeypatch.setattr(services, "find_gcs_addresses", lambda: frozenset())
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", no_init)
    (tmp_path / "ray").mkdir()
    return tmp_path / "ray"


@pytest.mark.parametrize("how", ["RAY_ADDRESS=auto", "--ray-address auto"])
def test_auto_naming_a_dead_cluster_is_one_line_at_once(ray_tmp, monkeypatch, how):
    port = _closed_port()
    (ray_tmp / "ray_current_cluster").write_text(f"127.0.0.1:{port}\n")
    if how == "RAY_ADDRESS=auto":
        monkeypatch.setenv("RAY_ADDRESS", "auto")
    else:
        monkeypatch.delenv("RAY_ADDRESS", raising=False)
    start = time.monotonic()
    with pytest.raises(ServiceError) as err:
        ray_pool.init_ray("auto" if how.startswith("--") else None)
    assert time.monotonic() - start < 10
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"no Ray cluster answers at 127.0.0.1:{port} (auto: the latest Ray")
    assert str(ray_tmp / "ray_current_cluster") in message and "start --head" in message


def test_auto_naming_a_hung_port_is_one_line_within_seconds(ray_tmp, monkeypatch):
    """Half dead: the port takes the connection but never answers (a stopped GCS, or another
    program that took the port since): Ray's check times out after 5 s instead of waiting."""
    with socket.create_server(("127.0.0.1", 0)) as silent:  # listens, never accepts or answers
        port = silent.getsockname()[1]
        (ray_tmp / "ray_current_cluster").write_text(f"127.0.0.1:{port}")
        monkeypatch.setenv("RAY_ADDRESS", "auto")
        start = time.monotonic()
        with pytest.raises(ServiceError) as err:
            ray_pool.init_ray()
    assert time.monotonic() - start < 20
    assert str(err.value).startswith(
        f"127.0.0.1:{port} (auto: the latest Ray started on this machine, in "
        f"{ray_tmp / 'ray_current_cluster'}) answers, but not as a Ray head does (no gRPC)"
    )


def test_auto_with_no_cluster_registered_is_one_line(ray_tmp, monkeypatch):
    monkeypatch.setenv("RAY_ADDRESS", "auto")
    with pytest.raises(ServiceError) as err:
        ray_pool.init_ray()
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(
        "--ray-address / RAY_ADDRESS auto: no Ray cluster is registered on this machine (no "
        f"{ray_tmp / 'ray_current_cluster'}, no running Ray); start one with"
    )
    assert message.endswith("or leave both unset for a private Ray")


def test_auto_takes_ray_address_first_as_ray_does(ray_tmp, monkeypatch):
    """`--ray-address auto` with RAY_ADDRESS naming a cluster: Ray joins RAY_ADDRESS; so is it checked."""
    port = _closed_port()
    (ray_tmp / "ray_current_cluster").write_text("127.0.0.1:1\n")
    monkeypatch.setenv("RAY_ADDRESS", f"127.0.0.1:{port}")
    with pytest.raises(
        ServiceError, match=rf"^no Ray cluster answers at 127.0.0.1:{port} \(auto: RAY_ADDRESS\)"
    ):
        ray_pool.init_ray("auto")


def test_auto_naming_a_live_head_joins_that_address(ray_tmp, monkeypatch):
    """A head that answers gRPC (here a stub that sends HTTP/2 SETTINGS): ray.init gets the address
    that auto resolved to, as Ray itself would have joined it."""
    import threading

    import ray

    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def answer():
        conn, _ = server.accept()
        with conn:
            conn.recv(64)
            conn.sendall(b"\x00\x00\x00\x04\x00\x00\x00\x00\x00")  # an empty SETTINGS frame

    threading.Thread(target=answer, daemon=True).start()
    (ray_tmp / "ray_current_cluster").write_text(f"127.0.0.1:{port}\n")
    monkeypatch.setenv("RAY_ADDRESS", "auto")
    joined = {}
    monkeypatch.setattr(ray, "init", lambda **kw: joined.update(kw))
    monkeypatch.setattr(ray_pool, "catch_sigterm", lambda: None)
    try:
        ray_pool.init_ray()
    finally:
        server.close()
    assert joined["address"] == f"127.0.0.1:{port}"


def test_pcpg_with_a_stale_ray_current_cluster_says_one_line(tmp_path):
    """The command a user runs: exit 2 and one `pcpg: error:` line well within 30 s, no C++ log."""
    (tmp_path / "ray").mkdir()
    port = _closed_port()
    (tmp_path / "ray" / "ray_current_cluster").write_text(f"127.0.0.1:{port}")
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_ADDRESS", "MLFLOW_TRACKING_URI")}
    env.update(RAY_TMPDIR=str(tmp_path), RAY_ADDRESS="auto")
    start = time.monotonic()
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "pcpg_dist.cli",
            "generate",
            str(ROOT / "experiments" / "quick.yaml"),
            "--out",
            str(tmp_path / "data"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
        env=env,
    )
    assert time.monotonic() - start < 30
    err = out.stderr.strip().splitlines()
    assert out.returncode == 2 and len(err) == 1, out.stderr[-2000:]
    assert err[0].startswith(f"pcpg: error: no Ray cluster answers at 127.0.0.1:{port} (auto: "), (
        err
    )
