"""Finding experiments and runs: a run by id or experiment name, a sweep's points, the
find-or-create of a run under a store lock, and the labels and provenance tags runs carry."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

import pcpg_dist
from pcpg_dist.common.errors import ServiceError
from pcpg_dist.common.provenance import git_commit, uv_lock_hash
from pcpg_dist.tracking.connection import _client, _retry, check_tracking_uri, end_quietly
from pcpg_dist.tracking.logged import _log_params
from pcpg_dist.tracking.store import (
    _artifact_root,
    check_store_holds,
    default_tracking_uri,
    prepare_store,
    store_lock,
)
from pcpg_dist.tracking.tags import (
    EXPERIMENT_KIND,
    PARENT,
    PARENT_ROLE,
    POINT_ROLE,
    ROLE,
    RUN_NAME,
    SWEEP_ROLE,
)


def find_run(target: str, uri: str | None = None):
    """``(run, uri)``: ``target`` as an MLflow run id, or as an experiment name its newest top-level
    pcpg run (the run of a `pcpg run` or of a `pcpg sweep`; never one point of a sweep nor an
    environment's run), at ``uri`` (default: :func:`default_tracking_uri`). The URI is checked
    first, and a ``sqlite:///`` store that does not exist is reported, never created."""
    from mlflow.exceptions import MlflowException

    uri = uri or default_tracking_uri()
    check_store_holds(target, uri)
    check_tracking_uri(uri)
    client = _client(uri)
    try:
        return client.get_run(target), uri
    except MlflowException:
        exp = client.get_experiment_by_name(target)
        if exp is None:
            raise ServiceError(
                f"{target!r} is neither a run's output folder, an MLflow run id nor an "
                f"experiment name at {uri}"
            ) from None
        run = newest_top_level_run(client, exp.experiment_id)
        if run is None:
            raise ServiceError(
                f"experiment {target!r} at {uri} has no pcpg run or sweep yet"
            ) from None
        return run, uri


def newest_top_level_run(client, exp_id: str):
    """The experiment's newest live run of a `pcpg run` (role ``parent`` with no parent run: a
    sweep's points carry the sweep as theirs) or of a `pcpg sweep` (role ``sweep``); ``None`` if
    it has neither. MLflow's search has no "tag is unset", so a page of a sweep's points is skipped."""
    newest = None
    for role in (PARENT_ROLE, SWEEP_ROLE):
        token, found = None, None
        while found is None:
            page = _retry(
                client.search_runs,
                [exp_id],
                filter_string=f"tags.`{ROLE}` = '{role}'",
                order_by=["attributes.start_time DESC"],
                max_results=200,
                page_token=token,
            )
            found = next((r for r in page if PARENT not in r.data.tags), None)
            token = page.token
            if not token:
                break
        if found is not None and (
            newest is None or (found.info.start_time or 0) > (newest.info.start_time or 0)
        ):
            newest = found
    return newest


def sweep_points_of(sweep_run_id: str, uri: str) -> list:
    """The live point runs of a sweep run, oldest first (each a `pcpg run` of one point; role
    ``point``, or ``parent`` when an older pcpg made it)."""
    client = _client(uri)
    exp_id = _retry(client.get_run, sweep_run_id).info.experiment_id
    runs = [
        r
        for role in (POINT_ROLE, PARENT_ROLE)
        for r in _runs_with(client, exp_id, {ROLE: role, PARENT: sweep_run_id})
    ]
    return sorted(runs, key=lambda r: (r.info.start_time or 0, r.info.run_id))


def open_experiment(name: str, uri: str | None):
    """Check the server, prepare the store, get or create the experiment (tagged for the classic
    runs table); returns (uri, client, experiment id)."""
    from mlflow.exceptions import MlflowException

    uri = uri or default_tracking_uri()
    check_tracking_uri(uri)
    prepare_store(uri)
    client = _client(uri)
    exp = _retry(client.get_experiment_by_name, name)
    if exp is None:
        with store_lock(uri, f"experiment:{name}"):
            exp = _retry(client.get_experiment_by_name, name)
            if exp is None:
                try:
                    _retry(
                        client.create_experiment,
                        name,
                        artifact_location=_artifact_root(uri),
                        tags=dict([EXPERIMENT_KIND]),
                    )
                except MlflowException as e:  # created on another machine in the meantime
                    if getattr(e, "error_code", "") != "RESOURCE_ALREADY_EXISTS":
                        raise
                exp = _retry(client.get_experiment_by_name, name)
    if exp.tags.get(EXPERIMENT_KIND[0]) is None:
        _retry(client.set_experiment_tag, exp.experiment_id, *EXPERIMENT_KIND)
    return uri, client, exp.experiment_id


def _runs_with(client, exp_id: str, tags: dict[str, str], parent: str | None = ...) -> list:
    """Live runs carrying ``tags`` (and, unless ``...``, exactly this parent run), oldest first."""
    flt = " and ".join(f"tags.`{k}` = '{v}'" for k, v in tags.items())
    runs, token = [], None
    while True:  # every page: a run of a thousand environments has more children than one holds
        page = _retry(
            client.search_runs, [exp_id], filter_string=flt, max_results=1000, page_token=token
        )
        runs.extend(page)
        token = page.token
        if not token:
            break
    if parent is not ...:
        runs = [r for r in runs if r.data.tags.get(PARENT) == parent]
    return sorted(runs, key=lambda r: (r.info.start_time or 0, r.info.run_id))


def _find_or_create(
    client,
    uri: str,
    exp_id: str,
    key: dict[str, str],
    parent: str | None,
    tags: dict[str, str],
    params: dict[str, str],
    legacy: dict[str, str] | None = None,
):
    """The run with identity ``key`` under ``parent``: found, or created under the identity's lock.

    Runs are found by their tags, never by name: a found run whose name differs from
    ``tags[RUN_NAME]`` (named by an older pcpg) is renamed. A run carrying ``legacy`` instead of
    ``key`` (an older pcpg's identity of the same run) is found too and retagged with ``key``.
    After creating, a search merges a twin made on another machine in the same instant: the
    earliest run wins and this process deletes its own (still empty) one.
    """
    lock = "run:" + json.dumps([exp_id, parent, key], sort_keys=True)
    with store_lock(uri, lock):
        found = _runs_with(client, exp_id, key, parent)
        if not found and legacy:
            found = _runs_with(client, exp_id, legacy, parent)
            for k, v in key.items():
                if found and found[0].data.tags.get(k) != v:
                    _retry(client.set_tag, found[0].info.run_id, k, v)
        if found:
            run = found[0]
            if RUN_NAME in tags and run.data.tags.get(RUN_NAME) != tags[RUN_NAME]:
                _retry(client.set_tag, run.info.run_id, RUN_NAME, tags[RUN_NAME])
            if run.info.status != "FINISHED":
                _retry(client.update_run, run.info.run_id, status="RUNNING")
                with killed_if_interrupted(client, run.info.run_id):
                    _log_params(client, run.info.run_id, params, have=run.data.params)
            return run.info.run_id, run.info.status == "FINISHED"
        all_tags = {**tags, **key, **({PARENT: parent} if parent else {})}
        mine = _retry(client.create_run, exp_id, tags=all_tags).info.run_id
        with killed_if_interrupted(client, mine):
            found = _runs_with(client, exp_id, key, parent)
            if found and found[0].info.run_id != mine:
                _retry(client.delete_run, mine)
                return found[0].info.run_id, found[0].info.status == "FINISHED"
            _log_params(client, mine, params)
        return mine, False


@contextlib.contextmanager
def killed_if_interrupted(client, run_id: str):
    """Mark ``run_id`` KILLED where Ctrl-C or SIGTERM lands inside the block: a run made but not
    yet handed to its caller (whose own cleanup marks it) would otherwise stay RUNNING."""
    try:
        yield
    except KeyboardInterrupt:
        end_quietly(client, run_id)
        raise


def _provenance_tags(out_dir: Path | None = None) -> dict[str, str]:
    tags = {
        "pcpg.git_commit": git_commit(),
        "pcpg.version": pcpg_dist.__version__,
        "pcpg.uv_lock": uv_lock_hash(),
    }
    if out_dir is not None:
        tags["pcpg.output_dir"] = str(out_dir)
    return tags


def _command(out_dir: Path) -> str:
    try:
        return str(
            json.loads((Path(out_dir) / "summary" / "run.json").read_text()).get("command") or ""
        )
    except (OSError, ValueError, AttributeError):
        return ""
