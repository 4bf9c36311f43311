"""Memory checks made before anything is allocated: a config or a data file whose largest single
allocation would not fit in half this machine's memory is refused with what to lower."""

from __future__ import annotations

import os


def machine_memory() -> int:
    """Physical memory of this machine in bytes (16 GiB when the OS does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 16 << 30


def gib(n_bytes: float) -> str:
    """A byte count as the messages print it (``12.3 GiB``)."""
    return f"{n_bytes / (1 << 30):.1f} GiB"


def check_memory(needed: float, what: str, lower: str) -> None:
    """Refuse a config whose largest single allocation (estimated from the config alone, before
    anything is allocated) would not fit in half this machine's memory; say what to lower."""
    budget = machine_memory() // 2
    if needed > budget:
        raise ValueError(
            f"{what} needs about {gib(needed)} of memory at once, more than half of this "
            f"machine's {gib(machine_memory())}: lower {lower}"
        )
