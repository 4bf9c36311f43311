"""The trained agents of a sweep as one MLflow pyfunc model (models-from-code: nothing pickled).

``mlflow.pyfunc.load_model(f"runs:/{run_id}/agents").predict(df)`` returns one action per row of
``df``, which has columns ``env`` (optional when the sweep has one environment), ``style`` (the
cluster index k), ``p`` (skill level), optional ``seed`` (default: the first), optional ``valid``
(bitmask of valid actions; default all valid) and the state features ``s0..s{d-1}``.
"""

from __future__ import annotations

from pathlib import Path

import mlflow.pyfunc
import numpy as np
import pandas as pd


class PcpgAgents(mlflow.pyfunc.PythonModel):
    def load_context(self, context) -> None:
        from pcpg_dist.bc import TrainedCells

        root = Path(context.artifacts["agents"])
        self.ensembles = {}
        for env_dir in sorted(p for p in root.iterdir() if p.is_dir()):
            parts = [TrainedCells.load(p) for p in sorted(env_dir.glob("*.pt"))]
            self.ensembles[env_dir.name] = TrainedCells.concat(parts)

    def predict(self, context, model_input: pd.DataFrame, params=None) -> np.ndarray:
        from pcpg_dist.errors import DataError
        from pcpg_dist.ranking import fmt

        df = pd.DataFrame(model_input)
        out = np.empty(len(df), np.int64)
        for i, row in enumerate(df.to_dict("records")):
            env = row.get("env") or next(iter(self.ensembles))
            if env not in self.ensembles:
                raise DataError(f"row {i}: env {env!r} not in this model ({sorted(self.ensembles)})")
            ens = self.ensembles[env]
            seed = int(row["seed"]) if "seed" in row else min(s.seed for s in ens.specs)
            key = f"k{int(row['style'])}-p{fmt(float(row['p']))}-s{seed}"
            states = np.array([[row[f"s{j}"] for j in range(ens.state_dim)]], np.float32)
            bits = int(row.get("valid", (1 << ens.n_actions) - 1))
            valid = ((bits >> np.arange(ens.n_actions)) & 1).astype(bool)[None]
            out[i] = ens.predict(states, valid, key)[0]
        return out


mlflow.models.set_model(PcpgAgents())
