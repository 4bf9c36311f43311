"""pcpg-corridor: a tiny third-party domain for pcpg-dist, registered as ``corridor``."""

from pcpg_corridor.domain import CorridorDomain, CorridorSettings, __version__

__all__ = ["CorridorDomain", "CorridorSettings", "__version__"]
