"""What the PCPG paper reports for MiniDungeons: it has results for the domain (so reports show
the paper's findings beside a run's) but no numbers or domain settings recorded here."""

from __future__ import annotations

from pcpg_dist.domains.base import PaperResults

PAPER = PaperResults()
