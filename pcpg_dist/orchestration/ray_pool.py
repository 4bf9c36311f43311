"""Starting or joining Ray, checking what a cluster can run, and running remote tasks.

Embedded default: a private Ray on this machine's CPUs that listens on 127.0.0.1 only, even when
another cluster (``ray start``) runs on the machine. With ``--ray-address`` or ``RAY_ADDRESS`` the
same code joins that cluster and ships the project's own code to its workers (``py_modules``), so
nodes need only the locked dependencies and no shared disk: tasks take their inputs as arguments
and return their results as values; only the driver writes files.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from pcpg_dist.common import errors
from pcpg_dist.common.commands import command
from pcpg_dist.common.devices import available_cpus, worker_env
from pcpg_dist.common.errors import ConfigError, ServiceError, catch_sigterm, first_line
from pcpg_dist.orchestration.nodes import node_capacities

# Ray's `uv run` hook would start every worker through `uv run` in the driver's project folder: it
# breaks outside that folder and costs ~20 s locally. The package ships itself instead (below).
os.environ.setdefault("RAY_ENABLE_UV_RUN_RUNTIME_ENV", "0")
# A raylet waits this long for its node's agents; Ray's default fails nodes on a busy laptop.
os.environ.setdefault("RAY_raylet_start_wait_time_s", "120")


# A private Ray's object store, and its spill and restore workers (Ray's default is up to four
# of each): every process that touches the store keeps its pages in its RSS, and each I/O
# worker is a Python process (docs/scale.md, measured on a million-trajectory streamed run).
# RAY_max_io_workers in the environment still decides (the system config would override it).
PRIVATE_STORE_BYTES = 200_000_000
PRIVATE_IO_WORKERS = 2


def _disable_uv_hook() -> None:
    """The flag is read from ray_constants at init time; set it there too if ray was imported."""
    from ray._private import ray_constants

    flag = os.environ["RAY_ENABLE_UV_RUN_RUNTIME_ENV"]
    ray_constants.RAY_ENABLE_UV_RUN_RUNTIME_ENV = flag not in ("0", "false", "False")


@contextlib.contextmanager
def _private_node() -> Iterator[None]:
    """Start a private node that keeps to itself, by two patches held only during ``ray.init``:

    - keep ``_node_ip_address="127.0.0.1"`` as given: Ray 2.60's ``ray.init`` swaps a loopback
      address for the machine's network address, and its servers then listen on every interface.
      On loopback, GCS, raylet and workers listen on 127.0.0.1 only (tests/ops/test_ray_cluster.py);
    - let the node's dashboard agent take a free port instead of Ray's fixed default (52365): a
      `ray start` cluster begun on the same machine while a run holds that port gets a head
      whose agent cannot bind it, and that head refuses every `ray job submit`.
    """
    from ray._private import node, services

    original_resolve = getattr(services, "resolve_ip_for_localhost", None)
    if original_resolve is not None:
        services.resolve_ip_for_localhost = lambda host: host
    original_node_init = node.Node.__init__

    def node_init(self, ray_params, *args, **kwargs):
        ray_params.dashboard_agent_listen_port = 0  # 0 = any free port (the agent reports it)
        original_node_init(self, ray_params, *args, **kwargs)

    node.Node.__init__ = node_init
    try:
        yield
    finally:
        node.Node.__init__ = original_node_init
        if original_resolve is not None:
            services.resolve_ip_for_localhost = original_resolve


def package_runtime_env() -> dict[str, Any]:
    """What a cluster's workers need from the driver: this package's code (not its caches)."""
    import pcpg_dist

    return {
        "py_modules": [str(Path(pcpg_dist.__file__).parent)],
        "env_vars": worker_env(),
        "excludes": ["__pycache__", "*.pyc"],
    }


def init_ray(address: str | None = None, num_cpus: int | None = None) -> None:
    """Join ``address`` (or ``RAY_ADDRESS``) if given, else start a private local Ray; idempotent."""
    import ray

    if ray.is_initialized():
        return
    address = address or os.environ.get("RAY_ADDRESS") or None
    _disable_uv_hook()
    address, found = _resolve_auto() if address == "auto" else (address, "")
    if address:
        _check_port(address, found=found)
    try:
        if address:
            ray.init(
                address=address,
                log_to_driver=False,
                runtime_env=package_runtime_env(),
                logging_level=logging.WARNING,
            )
        else:
            # address="local": never join a `ray start` cluster by accident (it would refuse
            # num_cpus); 127.0.0.1: a private instance is not reachable from the network.
            os.environ.pop("RAY_ADDRESS", None)
            for attempt in range(3):
                try:
                    with _private_node():
                        ray.init(
                            address="local",
                            num_cpus=num_cpus or available_cpus(),
                            include_dashboard=False,
                            object_store_memory=PRIVATE_STORE_BYTES,
                            log_to_driver=False,
                            runtime_env={"env_vars": worker_env()},
                            _system_config={}
                            if "RAY_max_io_workers" in os.environ
                            else {"max_io_workers": PRIVATE_IO_WORKERS},
                            logging_level=logging.WARNING,
                            _node_ip_address="127.0.0.1",
                        )
                    break
                except Exception as e:  # noqa: BLE001 - Ray raises a bare Exception for this
                    # Ray gives a new node a fixed 30 s to register; a busy laptop can miss it.
                    if "timed out during startup" not in str(e) or attempt == 2:
                        raise
                    ray.shutdown()
    except (ConnectionError, RuntimeError, ValueError) as e:
        hint = ""
        if address and isinstance(e, ConnectionError):  # Ray does not say when it is the token
            hint = (
                "; if the cluster uses token auth, this driver needs its token (RAY_AUTH_TOKEN_PATH, "
                "RAY_AUTH_TOKEN or ~/.ray/auth_token, with RAY_AUTH_MODE=token); one started with "
                "RAY_AUTH_MODE=disabled needs that here too"
            )
        raise ServiceError(
            f"cannot start or join Ray at {address or 'local'}: {first_line(e, 300)}{hint}"
        ) from None
    except Exception as e:
        if "timed out during startup" in str(e):
            raise ServiceError(
                "Ray did not start within its 30 s limit three times (is the machine "
                "overloaded?); retry when it is less busy"
            ) from None
        raise
    catch_sigterm()  # after ray.init: its core worker's handler would abort with a stack dump


def _resolve_auto() -> tuple[str, str]:
    """What ``auto`` stands for, as Ray 2.60's ``ray.init`` resolves it (``services.
    get_ray_address_from_environment``, without its log line), and where it was found. ``ray.init``
    waited ~14 min on a dead port that a stale ray_current_cluster named, printing its C++ log."""
    from ray._common.utils import get_ray_address_file
    from ray._private import services

    env, where = os.environ.get("RAY_ADDRESS", ""), get_ray_address_file(None)
    if env not in ("", "auto"):  # `--ray-address auto`: Ray takes RAY_ADDRESS first
        return env, " (auto: RAY_ADDRESS)"
    if latest := services.find_bootstrap_address(None):  # the latest `ray start` on this machine
        return latest, f" (auto: the latest Ray started on this machine, in {where})"
    if running := services.find_gcs_addresses():
        return next(iter(running)), " (auto: a Ray running on this machine)"
    raise ServiceError(
        f"--ray-address / RAY_ADDRESS auto: no Ray cluster is registered on this machine (no "
        f"{where}, no running Ray); start one with `{command('ray', 'start', '--head')}`, give "
        f"a cluster's HOST:PORT, or leave both unset for a private Ray"
    )


def _check_port(address: str, timeout: float = 5.0, found: str = "") -> None:
    """A cluster's head answers at ``address`` (``host:port`` or ``ray://host:port``; ``found``:
    where ``auto`` found it). Ray waits ~14 min on a dead one, printing its C++ log all the while."""
    import socket
    import urllib.parse

    try:
        url = urllib.parse.urlsplit(address if "://" in address else f"gcs://{address}")
        host, port = url.hostname, url.port
    except ValueError:
        host = port = None
    if not host or not port:
        raise ServiceError(
            f"--ray-address {address[:200]!r}{found}: expected HOST:PORT, ray://HOST:PORT or auto"
        )
    if "://" in address and url.scheme != "ray":  # http://HEAD:8265: the dashboard's (job submit)
        raise ServiceError(
            f"--ray-address {address[:200]!r}: expected HOST:PORT (the head's port, "
            f"`{command('ray', 'start', '--head', '--port')}`), ray://HOST:PORT or auto, not a {url.scheme}:// URL"
        )
    try:
        with socket.create_connection((host, port), timeout=timeout) as conn:
            speaks_grpc = _answers_http2(conn, timeout)
    except OSError as e:
        raise ServiceError(
            f"no Ray cluster answers at {address[:200]}{found} ({e}); start one with `{command('ray', 'start', '--head')}` "
            f"there or check --ray-address / RAY_ADDRESS"
        ) from None
    if not speaks_grpc and os.environ.get("RAY_USE_TLS", "0").lower() not in ("1", "true"):
        # an MLflow, database or web port: ray.init would wait there without end, printing its C++ log
        raise ServiceError(
            f"{address[:200]}{found} answers, but not as a Ray head does (no gRPC): is it another "
            f"service's port? the head's is `{command('ray', 'start', '--head', '--port')}` (default 6379)"
        )


def _answers_http2(conn, timeout: float) -> bool:
    """Whether the server on ``conn`` speaks HTTP/2, as gRPC (Ray's GCS and client server) does: it
    answers the client preface with a SETTINGS frame (type 4 in the 9-byte frame header)."""
    conn.settimeout(timeout)
    try:
        conn.sendall(b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00")
        head = b""
        while len(head) < 9:
            chunk = conn.recv(9 - len(head))
            if not chunk:
                break
            head += chunk
    except OSError:
        return False
    return len(head) == 9 and head[3] == 0x04


# --------------------------------------------------------------------------- what the cluster has
def check_resources(
    num_cpus: int, memory_bytes: float = 0.0, key: str = "runner.cpus_per_task"
) -> None:
    """Fail in one line before anything starts when no node can ever run a task of this size."""
    nodes = node_capacities()
    most_cpus = max((n["CPU"] for n in nodes), default=0.0)
    if num_cpus > most_cpus:
        raise ConfigError(
            f"{key}: {num_cpus} CPUs per task, but the largest Ray node has "
            f"{most_cpus:g}; set {key} to at most {int(most_cpus) or 1}"
            + ("" if most_cpus else " and start a node with CPUs")
        )
    most_mem = max((n["memory"] for n in nodes), default=0.0)
    if memory_bytes and most_mem and memory_bytes > most_mem:
        raise ConfigError(
            f"one task needs about {memory_bytes / 2**30:.1f} GiB (estimated from the "
            f"config), but the largest Ray node offers {most_mem / 2**30:.1f} GiB; use "
            f"less data per environment or a node with more memory"
        )


def _waiting_for(num_cpus: int, in_flight: int, num_gpus: float = 0.0) -> str:
    """What queued tasks wait for, when more are submitted than the cluster can run now."""
    import ray

    try:
        free, total = ray.available_resources(), ray.cluster_resources()
    except Exception:  # noqa: BLE001 - a status line must never break the run
        return ""
    what, need = ("GPU", num_gpus) if num_gpus else ("CPU", float(max(num_cpus, 1)))
    queued = in_flight - int(total.get(what, 0.0) // need)
    if free.get(what, 0.0) >= need or queued <= 0:
        return ""
    return f"{queued} queued, each waiting for {need:g} {what}; {free.get(what, 0.0):g} of {total.get(what, 0.0):g} free"


# --------------------------------------------------------------------------- running tasks
def run_tasks(
    fn: Callable[..., Any],
    calls: Sequence[tuple],
    description: str,
    num_cpus: int = 1,
    max_retries: int = 3,
    on_result: Callable[[int, Any], None] | None = None,
    show_progress: bool = True,
    max_in_flight: int | None = None,
    num_gpus: float | Sequence[float] = 0.0,
    options: dict[str, Any] | None = None,
) -> list[Any]:
    """Run ``fn(*args)`` for every ``args`` in ``calls`` as Ray tasks; results in call order.
    ``options``: Ray task options for every call (e.g. :func:`~pcpg_dist.orchestration.nodes.on_driver_node`).

    ``num_gpus`` (one for all calls, or one per call): GPUs a task asks for: Ray then runs it on a
    node with that share of a GPU free. (A Ray 2.60 task that asks for none still sees its node's
    GPUs, measured on an H100 machine; only the request keeps it off nodes without one and keeps
    more tasks than ``1 / num_gpus`` off one GPU.)

    ``max_retries`` re-runs a task whose worker process died (results are deterministic in the
    arguments, so a retry gives the same numbers). ``on_result(i, result)`` fires as each finishes,
    so callers can persist finished work before the rest is done; with ``on_result`` the result is
    not kept (``None`` in its place), so the driver never holds every result at once.
    ``max_in_flight`` bounds how many tasks are submitted at a time (a memory limit).
    """
    import ray

    from pcpg_dist.common.progress import progress_bar

    if not calls:
        return []
    check_resources(num_cpus)
    remote = ray.remote(num_cpus=num_cpus, max_retries=max_retries)(fn)
    if options:
        remote = remote.options(**options)
    one = isinstance(num_gpus, int | float)
    gpus = [float(num_gpus)] * len(calls) if one else [float(g) for g in num_gpus]
    limit = max(1, max_in_flight or len(calls))
    results: list[Any] = [None] * len(calls)

    def keep(i: int, value: Any) -> None:
        if on_result is not None:
            on_result(i, value)
        else:
            results[i] = value

    index: dict[Any, int] = {}
    submitted = 0

    def submit() -> None:
        nonlocal submitted
        while submitted < len(calls) and len(index) < limit:
            task = remote.options(num_gpus=gpus[submitted]) if gpus[submitted] else remote
            index[task.remote(*calls[submitted])] = submitted
            submitted += 1

    with progress_bar(description, total=len(calls), enabled=show_progress) as advance:
        try:
            submit()
            _collect(index, submit, advance, description, num_cpus, gpus, show_progress, keep)
        except BaseException:
            _abandon(list(index))
            raise
    return results


def fan_out(
    fn: Callable[..., Any], calls: Sequence[tuple], description: str, show_progress: bool = True
) -> list[Any]:
    """A domain's fan-out (:class:`pcpg_dist.domains.base.FanOut`) on Ray: every call a 1-CPU
    task, results in call order; what ``contract.generate`` is given where Ray is initialised."""
    return run_tasks(fn, calls, description, show_progress=show_progress)


def _collect(
    index: dict[Any, int],
    submit: Callable[[], None],
    advance: Callable[..., None],
    description: str,
    num_cpus: int,
    gpus: list[float],
    show_progress: bool,
    keep: Callable[[int, Any], None],
) -> None:
    """Wait for the tasks in ``index`` (ref -> call number), ``keep`` each result as it comes,
    submit more as slots free up; while nothing finishes, the bar says what the tasks wait for."""
    import ray

    idle_since = time.monotonic()
    while index:
        done, _ = ray.wait(list(index), num_returns=1, timeout=2.0)
        if not done:
            if time.monotonic() - idle_since > 5 and show_progress:
                waiting = _waiting_for(
                    num_cpus, len(index), max((gpus[i] for i in index.values()), default=0.0)
                )
                advance(0, description=f"{description} ({waiting})" if waiting else description)
            continue
        idle_since = time.monotonic()
        for ref in done:
            i = index.pop(ref)
            try:
                value = ray.get(ref)
            except ray.exceptions.RayTaskError as e:
                # A user mistake inside a task surfaces as the project's own one-line error.
                if (found := errors.pcpg_error_in(e)) is not None:
                    raise found from None
                raise
            keep(i, value)
            del value
            advance(1, description=description)
        submit()


def _abandon(refs: list[Any]) -> None:
    """After one task failed (or Ctrl-C): cancel the tasks still in flight and read those that
    already ended, so that Ray does not print their errors as unhandled after the one-line error."""
    import ray

    if not refs:
        return
    try:  # cleaning up must never replace the error being raised
        for ref in refs:
            ray.cancel(ref)
        done, _ = ray.wait(refs, num_returns=len(refs), timeout=10.0)
    except Exception:  # noqa: BLE001 - e.g. Ray already shut down
        return
    for ref in done:
        with contextlib.suppress(Exception):  # cancelled or failed: either way nothing to report
            ray.get(ref)
