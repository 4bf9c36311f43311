"""The pipeline: the stages declared once (:mod:`.declared`), one unit through them in-process
(:mod:`.units`), and the work of one job of each stage (:mod:`.tasks`)."""

from pcpg_dist.pipeline.units import (
    UnitClustering,
    UnitResult,
    cluster_unit,
    evaluate_unit,
    has_styles,
    partial_styles_note,
    plan_unit,
    run_unit,
)

__all__ = [
    "UnitClustering",
    "UnitResult",
    "cluster_unit",
    "evaluate_unit",
    "has_styles",
    "partial_styles_note",
    "plan_unit",
    "run_unit",
]
