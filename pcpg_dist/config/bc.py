"""Config of Step C (section ``bc``): the behavioural-cloning policy and its training."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from pcpg_dist.config.limits import MAX_COUNT
from pcpg_dist.config.schema import StrictModel


class BCConfig(StrictModel):
    """The behavioural-cloning policy and its training (Step C)."""

    hidden_layers: int = Field(3, ge=0, le=8, description="Hidden layers of the MLP (paper: 3).")
    hidden_size: int = Field(5, ge=1, le=1024, description="Units per hidden layer (paper: 5).")
    activation: Literal["relu", "tanh"] = Field(
        "tanh",
        description=(
            "Hidden activation. tanh by default: with 5-unit layers relu units die and some seeds "
            "lose a style (measured on the built-in grid game, docs/bc_and_evaluation.md)."
        ),
    )
    epochs: int = Field(
        2000,
        ge=0,
        le=MAX_COUNT,
        description=(
            "Adam steps of a full-batch cell (paper: '2000 episodes'; batch_size auto gives its "
            "minibatched cells the same number of steps); with an explicit batch_size, passes over "
            "the rows. Early stopping (stop_tol) may end a cell sooner."
        ),
    )
    batch_size: int | Literal["auto"] | None = Field(
        "auto",
        description=(
            "Rows per Adam step. auto: full batch (the paper) for a cell of up to 20,000 distinct "
            "rows (every cell of the paper's three games), minibatches of 4,096 for "
            "larger ones (a continuous log's cells), with the same budget of Adam steps. null: "
            "full batch always. A number: one epoch is one pass over a cell's rows, shuffled once "
            "from the cell's seed, in blocks of this many (numba engine only). The torch engine "
            "trains full batch under auto."
        ),
    )
    stop_tol: float = Field(
        1e-4,
        ge=0.0,
        le=1.0,
        description=(
            "Early stopping: a cell stops once its loss (mean cross-entropy over all its rows, in "
            "nats) improved by less than this over the last stop_window Adam steps (0: every cell "
            "takes all its epochs, as the paper)."
        ),
    )
    stop_window: int = Field(
        100,
        ge=1,
        le=MAX_COUNT,
        description="Adam steps between early-stopping checks (rounded up to whole epochs).",
    )
    lr: float = Field(0.01, gt=0.0, le=100.0, description="Adam learning rate (finite, > 0).")
    init: Literal["auto", "scratch", "no_clustering"] = Field(
        "auto",
        description=(
            "scratch (the paper): every agent starts from its seeded initialisation. no_clustering: "
            "the No Clustering agents train first, then every other agent (per cluster, corrupted "
            "labels) starts from the No Clustering agent of its p and seed and trains "
            "finetune_epochs on its own rows, so it keeps what all players share. auto: "
            "no_clustering where the unit's clustering verdict is 'weak evidence' or 'no "
            "evidence' (its clusters may not be styles), scratch where the styles were found or "
            "no confidence was measured (docs/bc_and_evaluation.md). The streamed pipeline "
            "trains from scratch."
        ),
    )
    finetune_epochs: int | None = Field(
        None,
        ge=0,
        le=MAX_COUNT,
        description=(
            "Epochs of the agents that start from No Clustering (null: epochs under init "
            "no_clustering, at most 100 under init auto)."
        ),
    )
    finetune_check: float = Field(
        0.5,
        ge=0.0,
        lt=1.0,
        description=(
            "Under init auto: the share of each fine-tuned agent's steps held out to check the "
            "fine-tune; an agent keeps it only where it predicts those steps better than the No "
            "Clustering agent it started from, else it is that agent (0: always fine-tune)."
        ),
    )
    betas: tuple[float, float] = Field(
        (0.9, 0.999), description="Adam beta1, beta2, each in [0, 1)."
    )
    eps: float = Field(1e-8, gt=0.0, le=1.0, description="Adam epsilon (finite, > 0).")
    device: Literal["cpu", "cuda", "auto"] = Field(
        "cpu",
        description=(
            "Where to train: 'auto' uses a GPU where there is one (the CPU with batch_size or engine "
            "numba, which run there only); 'cuda' fails without one. Ray tasks on a GPU ask for "
            "runner.gpus_per_task GPUs."
        ),
    )
    dtype: Literal["float32", "float64"] = Field("float32", description="Training precision.")
    engine: Literal["auto", "numba", "torch"] = Field(
        "auto",
        description=(
            "'numba': fused compiled CPU kernel (fastest on CPU, float32 only); 'torch': stacked "
            "baddbmm/bmm passes (runs on a GPU too); 'auto': numba on CPU in float32, else torch."
        ),
    )
    dedupe: bool = Field(
        True,
        description=(
            "Train on distinct (state, valid, action) rows weighted by their counts: same loss and "
            "gradient as the raw rows, far fewer rows where states repeat."
        ),
    )
    bucket_overhead_rows: int = Field(
        20000,
        ge=0,
        le=10**12,
        description=(
            "Padding (in cell-rows) worth one extra bucket; 0 = one bucket per distinct row count, "
            "very large = pad everything to the largest cell."
        ),
    )

    @field_validator("batch_size")
    @classmethod
    def _batch_size(cls, v: int | str | None) -> int | str | None:
        if isinstance(v, int) and not 1 <= v <= 10**9:
            raise ValueError(
                f"batch_size must be auto, null or a number of rows in [1, 10^9], got {v}"
            )
        return v

    @field_validator("betas")
    @classmethod
    def _betas(cls, v: tuple[float, float]) -> tuple[float, float]:
        for i, b in enumerate(v):
            if not 0.0 <= b < 1.0:
                raise ValueError(f"Adam beta{i + 1} must lie in [0, 1), got {b}")
        return v

    @model_validator(mode="after")
    def _batch_engine(self) -> BCConfig:
        if isinstance(self.batch_size, int) and (
            self.engine == "torch" or self.device == "cuda" or self.dtype != "float32"
        ):
            raise ValueError(
                "batch_size needs the numba engine (device cpu, dtype float32, "
                "engine auto or numba); set batch_size: null for the others"
            )
        if self.engine == "numba" and (self.device == "cuda" or self.dtype != "float32"):
            raise ValueError(
                f"engine numba runs on the CPU in float32 only (got device {self.device}, "
                f"dtype {self.dtype}); use engine auto or torch"
            )
        return self
