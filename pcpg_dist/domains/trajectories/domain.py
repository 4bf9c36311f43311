"""``domain: trajectories``: the whole PCPG pipeline on a user's own logs.

Data: a Parquet step table, a folder of them, or ``minari:DATASET_ID`` (read by
:mod:`.table` / :mod:`.minari_io`, validated before anything is written). Units: one per ``env``
value, each with a seeded trajectory split. Step B ranks by ``trajectories.score``. With
``trajectories.gymnasium_env`` every trained agent is also rolled out in that Gymnasium env, and
the evaluation reports its return and length; the rollouts run as long as the longest logged
trajectory unless ``evaluation.max_steps`` is set (:mod:`.rollout_length`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from pcpg_dist.domains.base import Domain, DomainHooks, FanOut, ScoreFn, StreamSource, Unit
from pcpg_dist.domains.defaults import in_process
from pcpg_dist.domains.trajectories.settings import BUILTIN_SCORES, SECTIONS


def minari_fingerprint(dataset_id: str) -> list[list]:
    """Names, sizes and SHA-256 of a local Minari dataset's files (its content, for the cache key)."""
    import minari

    from pcpg_dist.common.errors import DataError, first_line
    from pcpg_dist.common.files import sha256_file

    try:
        root = Path(minari.storage.get_dataset_path(dataset_id))
    except Exception as e:  # noqa: BLE001 - minari raises several kinds for a bad id
        raise DataError(f"minari:{dataset_id}: {first_line(e)}") from None
    files = sorted(p for p in root.rglob("*") if p.is_file())
    return [[str(p.relative_to(root)), p.stat().st_size, sha256_file(p)] for p in files]


class TrajectoriesDomain(Domain):
    name = "trajectories"
    sections = SECTIONS

    @staticmethod
    def _skill_column(settings) -> str | None:
        return None if settings.score in BUILTIN_SCORES else settings.score

    def check_config(self, cfg) -> None:
        """The settings' own checks, then the Gymnasium env made, reset and stepped once, so that an
        unknown id or kwargs that only fail when the env runs stop the run at config load."""
        super().check_config(cfg)
        s = cfg.trajectories
        if s.gymnasium_env is not None:
            from pcpg_dist.domains.trajectories.gym_rollout import check_runs, make_env

            env = make_env(s.gymnasium_env, dict(s.gymnasium_kwargs))
            try:
                check_runs(env, s.gymnasium_env, dict(s.gymnasium_kwargs))
            finally:
                env.close()

    def data_key(self, cfg) -> list[Any]:
        from pcpg_dist.common.files import sha256_file
        from pcpg_dist.domains.trajectories.table_files import parquet_files

        s = cfg.trajectories
        if s.path.startswith("minari:"):
            content = minari_fingerprint(s.path.removeprefix("minari:"))
        else:
            content = [[f.name, sha256_file(f)] for f in parquet_files(Path(s.path))]
        return [
            self.name,
            s.model_dump(
                mode="json", exclude={"gymnasium_env", "gymnasium_kwargs", "gymnasium_success"}
            ),
            content,
        ]

    def data_source(self, cfg) -> dict[str, Any]:
        """The log's path (a file or a folder of Parquet files) or Minari dataset id."""
        path = cfg.trajectories.path
        if path.startswith("minari:"):
            return {"name": path, "type": "minari", "source": {"uri": path}}
        return {
            "name": Path(path).name,
            "type": "local",
            "source": {"uri": Path(path).resolve().as_uri()},
        }

    def stream_source(self, cfg) -> StreamSource | None:
        """A Parquet log or a local Minari dataset to stream (trajectories.stream, or 'auto'
        above stream_above_steps rows), known from the files' or the dataset's metadata only;
        small logs load whole."""
        s = cfg.trajectories
        if s.stream == "off":
            return None
        if s.path.startswith("minari:"):
            from pcpg_dist.domains.trajectories.minari_stream import minari_stream_source

            found = minari_stream_source(s, cfg.name)
        else:
            from pcpg_dist.domains.trajectories.stream_meta import stream_source

            found = stream_source(s, cfg.name)
        if found is not None and cfg.clustering.move_features is not None:
            from pcpg_dist.common.errors import DataError

            raise DataError(
                f"clustering.move_features: {s.path} streams ({found.steps} steps; "
                f"trajectories.stream {s.stream!r}), and a streamed run clusters by k-means on "
                "summaries; give trajectories.stream: off to cluster by the moves' features"
            )
        return found

    def generate(self, cfg, show_progress: bool = True, fan_out: FanOut = in_process):
        from pcpg_dist.domains.trajectories.table import datasets_from_table
        from pcpg_dist.domains.trajectories.table_files import (
            StepTable,
            read_step_table,
            safe_env_name,
        )

        s = cfg.trajectories
        n_actions = s.n_actions
        if s.path.startswith("minari:"):
            from pcpg_dist.domains.trajectories.minari_read import read_minari

            dataset_id = s.path.removeprefix("minari:")
            table, meta = read_minari(dataset_id)
            step = StepTable(table, s.path, safe_env_name(dataset_id))
            n_actions = n_actions or meta.get("n_actions")
        else:
            step = read_step_table(s.path)
        return datasets_from_table(step, n_actions=n_actions, skill_column=self._skill_column(s))

    def manifest(self, cfg, datasets) -> dict[str, Any]:
        return {"seed_entropy": {"base": cfg.seed}, "source": cfg.trajectories.path}

    def units(self, cfg, datasets) -> list[Unit]:
        """One unit per logged env, each checked against the Gymnasium env; the longest logged
        trajectory is noted on the settings here, once per run, for the rollouts' length."""
        units = super().units(cfg, datasets)
        s = cfg.trajectories
        if s.gymnasium_env is not None:
            from pcpg_dist.domains.trajectories.gym_rollout import check_compatible, make_env
            from pcpg_dist.domains.trajectories.rollout_length import (
                longest_logged,
                note_rollout_steps,
                warn_short_time_limit,
            )

            longest = longest_logged(datasets)
            s._longest_logged = longest  # travels with the config to the rollouts' workers
            env = make_env(s.gymnasium_env, dict(s.gymnasium_kwargs))
            try:
                for u in units:
                    check_compatible(env, u.dataset.state_dim, u.dataset.n_actions)
                warn_short_time_limit(env, s.gymnasium_env, longest)
            finally:
                env.close()
            note_rollout_steps(cfg.evaluation, longest)
        return units

    def evaluation_key(self, cfg) -> list[Any]:
        """The rollout env and how long and how judged its episodes are: a changed success rule
        or longer logs must not reuse an evaluation cached before."""
        s = cfg.trajectories
        if s.gymnasium_env is None:
            return []
        from pcpg_dist.domains.trajectories.rollout_length import rollout_steps

        steps = rollout_steps(cfg.evaluation, self._longest_logged(cfg))
        return [s.gymnasium_env, dict(s.gymnasium_kwargs), s.gymnasium_success, steps]

    def _longest_logged(self, cfg) -> int:
        """The longest logged trajectory's number of actions: noted by :meth:`units`, else (a
        config that never went through it) read from the logs again."""
        from pcpg_dist.domains.trajectories.rollout_length import longest_logged

        s = cfg.trajectories
        if s._longest_logged is None:
            s._longest_logged = longest_logged(self.generate(cfg, show_progress=False))
        return s._longest_logged

    def score(self, cfg) -> ScoreFn:
        how = cfg.trajectories.score
        if how == "return":
            return lambda ds: ds.returns
        if how == "length":
            return lambda ds: ds.lengths.astype(np.float64)
        if how == "-length":
            return lambda ds: -ds.lengths.astype(np.float64)

        def column(ds) -> np.ndarray:
            if ds.skill is None:
                from pcpg_dist.common.errors import DataError

                raise DataError(
                    f"dataset {ds.env}: no recorded skill column '{how}' (trajectories.score)"
                )
            return ds.skill

        return column

    def hooks(self, cfg, unit: str) -> DomainHooks | None:
        s = cfg.trajectories
        if s.gymnasium_env is None:
            return None
        from pcpg_dist.domains.trajectories.gym_rollout import rollout
        from pcpg_dist.domains.trajectories.rollout_length import rollout_steps

        max_steps = rollout_steps(cfg.evaluation, self._longest_logged(cfg))

        def run(policy, n, rng):
            return rollout(
                s.gymnasium_env,
                dict(s.gymnasium_kwargs),
                policy,
                n,
                rng,
                max_steps=max_steps,
                success_rule=s.gymnasium_success,
            )

        return DomainHooks(rollout=run)
