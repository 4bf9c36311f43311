"""Logs whose styles are known for some trajectories only: style scoring is left out, and said."""

from __future__ import annotations

import logging

import pandas as pd

from pcpg_dist.config import parse_config
from pcpg_dist.orchestration.cache import Cache
from pcpg_dist.orchestration.points import load_units


def test_a_log_with_some_unknown_styles_says_what_is_left_out(tmp_path, caplog):
    """style -1 (unknown) beside labelled trajectories dropped accuracy, ARI, NMI and the ceiling
    from the results without a word (the probe: two thirds labelled, nothing said)."""
    rows = []
    for traj, style in enumerate([-1, 0, 1, 0, 1, -1]):
        rows += [
            {
                "trajectory": traj,
                "t": t,
                "s0": float(t * (style + 2)),
                "action": a,
                "reward": 1.0,
                "style": style,
            }
            for t, a in enumerate([style % 2, 1, -1])
        ]
    log = tmp_path / "log.parquet"
    pd.DataFrame(rows).to_parquet(log, index=False)
    cfg = parse_config(
        {
            "name": "partial",
            "domain": "trajectories",
            "trajectories": {"path": str(log), "score": "return"},
            "clustering": {"k": 2},
        },
        source="partial",
    )
    with caplog.at_level(logging.WARNING, logger="pcpg_dist"):
        (unit,), _ = load_units(cfg, Cache(tmp_path / "cache"), show_progress=False)
    assert [r.getMessage() for r in caplog.records] == [
        f"{unit.name}: 2 of 6 trajectories have style -1 (unknown): the scores against the true styles "
        "(clustering accuracy, ARI, NMI, the supervised ceiling, the corruption study) need every "
        "trajectory labelled and are left out"
    ]
    caplog.clear()
    pd.DataFrame([{**r, "style": max(r["style"], 0)} for r in rows]).to_parquet(log, index=False)
    load_units(cfg, Cache(tmp_path / "cache"), show_progress=False)  # all labelled: nothing to say
    pd.DataFrame([{**r, "style": -1} for r in rows]).to_parquet(log, index=False)
    load_units(
        cfg, Cache(tmp_path / "cache"), show_progress=False
    )  # none labelled: nothing is lost
    assert caplog.records == []


def test_pcpg_run_says_it_too(ray_session, tmp_path, caplog, monkeypatch):
    """The warning lived in load_units, which `pcpg run` and sweeps do not call: they were silent."""
    import pytest

    from pcpg_dist.api.run import run_experiment
    from pcpg_dist.orchestration.runner import Batch

    class Stop(Exception):
        pass

    rows = [
        {"trajectory": traj, "t": t, "s0": float(t), "action": a, "reward": 1.0, "style": style}
        for traj, style in enumerate([-1, 0, 1, 0])
        for t, a in enumerate([traj % 2, -1])
    ]
    log = tmp_path / "log.parquet"
    pd.DataFrame(rows).to_parquet(log, index=False)
    cfg = parse_config(
        {
            "name": "partial",
            "domain": "trajectories",
            "trajectories": {"path": str(log), "score": "return"},
            "clustering": {"k": 2},
        },
        source="partial",
    )
    monkeypatch.setattr(
        Batch, "run_jobs", lambda *a, **k: (_ for _ in ()).throw(Stop())
    )  # stop at Step A
    with caplog.at_level(logging.WARNING, logger="pcpg_dist"), pytest.raises(Stop):
        run_experiment(cfg, workdir=tmp_path / "runs", track=False, show_progress=False)
    assert [r.getMessage().split(":")[1] for r in caplog.records] == [
        " 1 of 4 trajectories have style -1 (unknown)"
    ]
