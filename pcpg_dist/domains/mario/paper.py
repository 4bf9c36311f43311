"""What the PCPG paper reports for Mario: no numbers of its own here, but the state it reads (the
counters and the event id as one number) is part of the protocol a reproduction must use."""

from __future__ import annotations

from pcpg_dist.domains.base import PaperResults
from pcpg_dist.domains.mario.settings import MarioLoadConfig

PAPER = PaperResults(
    protocol=(
        ("mario.event", "id"),  # the state (j, k, r, c, d, e): the event id as one number
        ("mario.counters", True),
        ("mario.increments", False),
    ),
    absent_means={
        "mario.event": "id",  # runs before the setting (2026-11-21) read the event id as a number
        **{
            f"mario.{name}": MarioLoadConfig.model_fields[name].default
            for name in ("counters", "increments")
        },
    },
)
