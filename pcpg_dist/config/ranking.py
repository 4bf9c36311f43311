"""Config of Step B (section ``ranking``): how trajectories are scored, split and thresholded."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from pcpg_dist.config.limits import MAX_SEED
from pcpg_dist.config.schema import StrictModel

DEFAULT_PS = (1.0, 0.75, 0.5, 0.25, 0.1)


class RankConfig(StrictModel):
    """How trajectories are scored, split and thresholded (Step B)."""

    beta: float = Field(
        0.1,
        gt=0.0,
        le=1.0,
        description=(
            "Penalty factor of Performance(X) for trajectories that do not end in a goal state "
            "(paper: 0.1)."
        ),
    )
    ps: tuple[float, ...] = Field(
        DEFAULT_PS,
        min_length=1,
        description=(
            "Fractions p of each cluster kept after ranking (top p by Performance); each in (0, 1]."
        ),
    )
    test_fraction: float = Field(
        0.2,
        gt=0.0,
        lt=1.0,
        description=(
            "Fraction of trajectories held out for testing, split before thresholding (every run "
            "evaluates its agents on them, so at least one is held out)."
        ),
    )
    split_seed: int = Field(
        0,
        ge=0,
        le=MAX_SEED,
        description=(
            "Seed of the train/test split; one split per environment, shared by all seeds' models so "
            "that PCPG and No Clustering are compared on the same unseen trajectories."
        ),
    )
    corruption_seed: int = Field(
        0,
        ge=0,
        le=MAX_SEED,
        description=(
            "Base seed of the label-corruption draws (combined with each model seed and level c)."
        ),
    )
    corruption_mode: Literal["wrong", "random"] = Field(
        "random",
        description=(
            "How a corrupted label is drawn: 'wrong' = uniformly among the k-1 other labels (c = 1: "
            "every label wrong); 'random' = uniformly among all k labels (c = 1: a random "
            "clustering, the No Clustering situation with 1/k of the data)."
        ),
    )
    style_margin: float = Field(
        0.0,
        ge=0.0,
        le=1e6,
        description=(
            "Style-aware Step B (not in the paper; 0 = the paper's ranking): a trajectory whose "
            "cluster is less than this many nats more likely than the next best ranks after every "
            "other trajectory of its cluster, in the training and test subsets alike, so the top p "
            "holds the cluster's skilled players of its style, not short trajectories that fit "
            "several styles. Needs a clusterer with a likelihood (greedy_mix, bag_auto on discrete "
            "states, policy_mix); 1 is the measured choice (docs/results.md)."
        ),
    )

    @field_validator("ps")
    @classmethod
    def _ps_in_range(cls, ps: tuple[float, ...]) -> tuple[float, ...]:
        for p in ps:
            if not 0.0 < p <= 1.0:
                raise ValueError(f"every p must lie in (0, 1], got {p}")
        if len(set(ps)) != len(ps):
            raise ValueError(f"ps has repeated values: {ps}")
        return ps
