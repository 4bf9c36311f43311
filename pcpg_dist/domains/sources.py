"""The domain calls that say where the data comes from, checked at the boundary as every call
in :mod:`.contract` is: :func:`data_source` (lineage) and :func:`stream_source` (a log to stream
through ``ray.data`` rather than load into one process)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from pcpg_dist.domains.contract import _fail, _kind, calling, the_domain

if TYPE_CHECKING:
    from pcpg_dist.config import ExperimentConfig
    from pcpg_dist.domains.base import Domain


def stream_source(cfg: ExperimentConfig, domain: Domain | None = None):
    """The log to stream (:meth:`Domain.stream_source`), checked: None or a StreamSource."""
    from pcpg_dist.domains.base import StreamSource

    domain = the_domain(cfg, domain)
    with calling(domain, "stream_source"):
        found = domain.stream_source(cfg)
    ok = found is None or (isinstance(found, StreamSource) and found.files and found.states)
    if not ok:
        raise _fail(domain, "stream_source", f"returned {_kind(found)}, not a StreamSource or None")
    return found


def data_source(cfg: ExperimentConfig, domain: Domain | None = None) -> dict[str, Any]:
    """Where the domain's data comes from (:meth:`Domain.data_source`), checked: a mapping with a
    short ``name`` and ``type`` and a JSON-able ``source`` mapping."""
    import json

    domain = the_domain(cfg, domain)
    with calling(domain, "data_source"):
        found = domain.data_source(cfg)
    if not isinstance(found, dict):
        raise _fail(domain, "data_source", f"returned {_kind(found)}; it must return a dict")
    name, kind, source = found.get("name"), found.get("type"), found.get("source")
    if not (isinstance(name, str) and 0 < len(name) <= 200):
        raise _fail(domain, "data_source", "returned no 'name' string of 1 to 200 characters")
    if not (isinstance(kind, str) and 0 < len(kind) <= 36):
        raise _fail(domain, "data_source", "returned no 'type' string of 1 to 36 characters")
    try:
        text = json.dumps(source, sort_keys=True, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise _fail(
            domain, "data_source", f"returned a 'source' that is not JSON-able ({e})"
        ) from None
    if not isinstance(source, dict):
        raise _fail(
            domain, "data_source", f"returned a 'source' that is {_kind(source)}; it must be a dict"
        )
    return {"name": name, "type": kind, "source": json.loads(text)}
