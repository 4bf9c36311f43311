"""Checks of a run's outputs against its inputs, made from the config before any work."""

from __future__ import annotations

from pathlib import Path
from urllib.parse import unquote, urlparse

from pcpg_dist.common.errors import ConfigError
from pcpg_dist.domains import sources


def check_apart_from_inputs(cfg, out: Path, option: str) -> None:
    """Refuse an output folder that is, or lies inside, a folder the data is read from (a
    folder of step tables: the outputs would be read back as input next time). One line, before
    any work."""
    uri = str(sources.data_source(cfg)["source"].get("uri", ""))
    if not uri.startswith("file://"):
        return
    source = Path(unquote(urlparse(uri).path))
    if not source.is_dir():
        return
    where = Path(out).resolve()
    if where == source.resolve() or where.is_relative_to(source.resolve()):
        raise ConfigError(
            f"{option} {out}: inside the input folder {source} (the data is read from it, and "
            f"what pcpg writes there would be read back as input); choose a folder outside it"
        )
