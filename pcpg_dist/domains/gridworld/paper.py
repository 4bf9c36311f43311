"""What the PCPG paper reports for GridWorld: its numbers (../shared/PAPER.md) and the settings of
its GridWorld experiments a run must use to be a reproduction."""

from __future__ import annotations

from pcpg_dist.domains.base import PaperResults

PAPER = PaperResults(
    numbers={
        "clustering accuracy": "0.66",
        "cross-accuracy diagonal (Table 4)": "0.57 / 0.64 / 0.63 / 0.69",
        "reward distance, PCPG (Table 3)": "8.66 / 44.85 / 46.28 / 50.79",
        "reward distance, random (Table 3)": "33.05 / 180.84 / 180.12 / 192.42",
    },
    protocol=(
        ("clustering.k", 4),
        ("gridworld.environments", ["E1", "E2", "E3", "E4", "E5"]),
        ("gridworld.random_layouts", None),
        ("pbtg.episodes", 20000),
        ("pbtg.trajectories_per_style", 8000),
        ("pbtg.dataset_per_style", 1000),
    ),
)
