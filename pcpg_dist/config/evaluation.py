"""Config of the evaluation (section ``evaluation``): rollouts, corruption study, figures."""

from __future__ import annotations

from pydantic import Field, field_validator, model_validator

from pcpg_dist.common.memory import check_memory
from pcpg_dist.config.limits import MAX_COUNT, MAX_EPISODE_STEPS, MAX_SEED
from pcpg_dist.config.schema import StrictModel


class EvalConfig(StrictModel):
    """What the evaluation computes and how agents act in rollouts."""

    rollouts_per_policy: int = Field(
        100, ge=1, le=MAX_COUNT, description="Rollout episodes per trained policy."
    )
    greedy: bool = Field(
        True,
        description=(
            "Rollout actions: True = argmax over valid actions, False = sampled from the softmax."
        ),
    )
    max_steps: int = Field(
        100, ge=1, le=MAX_EPISODE_STEPS, description="Step limit of a rollout episode."
    )
    corruption_levels: tuple[float, ...] = Field(
        (0.0, 0.2, 0.4, 0.6, 0.8, 1.0),
        max_length=1000,
        description=(
            "Fractions c of cluster labels replaced by wrong ones in the corruption study; each in [0, 1]."
        ),
    )
    corruption_ps: tuple[float, ...] = Field(
        (1.0,),
        min_length=1,
        max_length=1000,
        description=(
            "p values of the corruption study's cells (default: all data, to isolate the labels)."
        ),
    )
    reward_p: float = Field(
        1.0,
        gt=0.0,
        le=1.0,
        description=(
            "p of the models whose rollouts give the headline reward distance (Table 3) and Fig. 8; "
            "the table lists every p. 1.0 = pi_k trained on its whole cluster (a small p keeps the "
            "shortest trajectories, which can be ones that skipped their style's bonus)."
        ),
    )
    rollout_seed: int = Field(
        0, ge=0, le=MAX_SEED, description="Base seed of the rollout generators."
    )
    figures: bool = Field(True, description="Write PNG figures beside the tables.")

    @field_validator("corruption_levels")
    @classmethod
    def _levels(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        for c in v:
            if not 0.0 <= c <= 1.0:
                raise ValueError(f"every corruption level c must lie in [0, 1], got {c}")
        if len(set(v)) != len(v):
            raise ValueError("corruption_levels has repeated values")
        return v

    @field_validator("corruption_ps")
    @classmethod
    def _ps(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        for p in v:
            if not 0.0 < p <= 1.0:
                raise ValueError(f"every p must lie in (0, 1], got {p}")
        if len(set(v)) != len(v):
            raise ValueError("corruption_ps has repeated values")
        return v

    @model_validator(mode="after")
    def _memory(self) -> EvalConfig:
        # a policy's rollouts run as one batch: states, actions and masks of every step kept
        check_memory(
            self.rollouts_per_policy * (self.max_steps + 1) * 64.0,
            f"one policy's {self.rollouts_per_policy} rollouts of up to {self.max_steps} steps",
            "evaluation.rollouts_per_policy or evaluation.max_steps",
        )
        return self
