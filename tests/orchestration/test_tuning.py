"""`pcpg tune`: the search space, the best config, MLflow child runs, resume, failing trials, and
the same on a real PostgreSQL server (team mode)."""

from __future__ import annotations

import contextlib
import sys
import uuid
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from pcpg_dist.api.tune import tune
from pcpg_dist.cli import main
from pcpg_dist.common.errors import ConfigError, DataError
from pcpg_dist.config import load_config, parse_config
from pcpg_dist.orchestration.tuning import (
    PARAMS,
    TuneConfig,
    apply_params,
    best_config_data,
    open_storage,
    rdb_url,
    suggest,
    trial_task,
    tune_settings,
)

ROOT = Path(__file__).resolve().parents[2]
POSTGRES = "postgresql://postgres@127.0.0.1:5432/test"  # local server, trust auth

TINY = {
    "name": "tinytune",
    "seed": 3,
    "seeds": [0],
    "gridworld": {
        "layout_dir": str(ROOT / "pcpg_dist" / "data" / "gridworld"),
        "environments": ["E1"],
    },
    "pbtg": {"episodes": 5000, "trajectories_per_style": 60, "dataset_per_style": 30},
    # these tests check the study, not the clustering (tests/stages does): no ceiling panel, and
    # with no confidence refits bag_auto fits greedy_mix alone instead of choosing among refitted
    # candidates, in every trial and in the best config's run
    "clustering": {
        "pretrain_epochs": 3,
        "dec_epochs": 2,
        "kmeans_n_init": 2,
        "ceiling": False,
        "confidence_runs": 0,
    },
    "ranking": {"ps": [1.0, 0.5]},
    "bc": {"epochs": 80},
    "runner": {"cpus_per_task": 1},
    "tuning": {
        "n_trials": 2,
        "parallel_trials": 2,
        "k_range": [2, 4],
        "lstm_hidden_sizes": [8],
        "latent_sizes": [4],
        "bc_layers_range": [1, 2],
        "bc_widths": [8, 16],
        "min_cluster_fraction": 0.0,
        "n_startup_trials": 2,
    },
}


def config(tmp_path: Path, **tuning) -> object:
    data = {**TINY, "tuning": {**TINY["tuning"], **tuning}}
    path = tmp_path / f"tiny-{uuid.uuid4().hex[:6]}.yaml"
    path.write_text(yaml.safe_dump(data))
    return load_config(path)


def unique(prefix: str) -> str:
    return f"{prefix}-{uuid.uuid4().hex[:10]}"


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    """One data cache for the module: every study below reuses the same generated dataset."""
    return tmp_path_factory.mktemp("tune-work")


def flaky_trial(datasets, cfg, tune, params, threads):
    """A trial that raises for k == 3 (pickled by value into the Ray workers)."""
    if params["k"] == 3:
        raise RuntimeError("boom: k=3 is broken on purpose")
    return trial_task(datasets, cfg, tune, params, threads)


def instant_trial(datasets, cfg, tune, params, threads):
    """A trial that trains nothing: for tests about the study around the trials."""
    return {"value": 0.5, "pruned": None, "metrics": {}}


def real_journal(path: Path) -> bytes:
    """A journal written by Optuna itself: a study, a user attribute, a finished trial."""
    import optuna
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    study = optuna.create_study(
        study_name="s", storage=JournalStorage(JournalFileBackend(str(path)))
    )
    study.set_user_attr("pcpg.objective_key", "abc")
    study.optimize(lambda t: t.suggest_int("k", 2, 4), n_trials=1)
    return path.read_bytes()


def tune_cli(tmp_path: Path, capsys, *args: str) -> tuple[int, str]:
    """`pcpg tune` on the tiny config; its exit code and stderr."""
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(TINY))
    code = main(
        ["tune", str(path), "--no-tracking", "--workdir", str(tmp_path / "work"), "--quiet", *args]
    )
    return code, capsys.readouterr().err


# ------------------------------------------------------------------------------ fast
def test_tuning_section_is_optional_and_validated(tmp_path):
    assert load_config(ROOT / "experiments" / "quick.yaml").tuning == TuneConfig()
    assert load_config(ROOT / "experiments" / "tune_gridworld.yaml").tuning.k_range == (2, 8)
    base = {"name": "x", "gridworld": TINY["gridworld"]}
    for bad, words in (
        ({"k_range": [5, 2]}, "tuning.k_range"),
        ({"bc_widths": [8, 8]}, "bc_widths"),
        ({"enqueue": [{"kk": 3}]}, "unknown parameter"),
        ({"penalty": -1}, "tuning.penalty"),
        ({"n_trails": 3}, "unknown key 'tuning.n_trails'"),
    ):
        with pytest.raises(ConfigError, match=words):
            parse_config({**base, "tuning": bad})


def test_suggest_fixes_single_value_dimensions_and_apply_sets_the_config(tmp_path):
    import optuna

    cfg = config(tmp_path, lstm_hidden_sizes=[8], latent_sizes=[4], bc_layers_range=[2, 2])
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0), direction="maximize")
    seen = []
    for _ in range(12):
        trial = study.ask()
        params = suggest(trial, cfg.tuning)
        assert set(params) == set(PARAMS)
        assert set(trial.params) == {"k", "bc_width"}  # fixed ones are not searched
        seen.append(params["k"])
        study.tell(trial, 0.0)
    assert set(seen) == {2, 3, 4}
    tuned = apply_params(
        cfg, {"k": 3, "lstm_hidden": 8, "latent": 4, "bc_layers": 2, "bc_width": 16}
    )
    assert (
        tuned.clustering.k,
        tuned.clustering.hidden_size,
        tuned.clustering.latent_size,
        tuned.bc.hidden_layers,
        tuned.bc.hidden_size,
    ) == (3, 8, 4, 2, 16)
    assert tuned.clustering.pretrain_epochs == cfg.clustering.pretrain_epochs
    # k_range may start at 1: that trial (and a best config with k = 1) corrupts nothing
    one = apply_params(cfg, {"k": 1, "lstm_hidden": 8, "latent": 4, "bc_layers": 2, "bc_width": 16})
    assert one.clustering.k == 1 and one.evaluation.corruption_levels == (0.0,)
    assert cfg.evaluation.corruption_levels != (0.0,)


def test_sizes_the_clusterer_ignores_are_not_searched(tmp_path):
    """greedy_mix (bag_auto on discrete states) has no LSTM: tuning its sizes would spend trials
    on a dimension that changes nothing. policy_mix uses clustering.hidden_size, not latent_size;
    bag_auto on continuous states is policy_mix."""
    from bc_toy import make_dataset

    from pcpg_dist.domains.base import Unit
    from pcpg_dist.orchestration.tuning import searched_space

    discrete = make_dataset(40, seed=0)  # grid positions: few distinct states
    continuous = replace(
        discrete,
        states=np.random.default_rng(0).normal(size=discrete.states.shape).astype(np.float32),
    )
    grid, cont = (Unit("u", d, np.arange(4)) for d in (discrete, continuous))
    cfg = config(tmp_path, lstm_hidden_sizes=[8, 16], latent_sizes=[4, 8])
    for method, unit, unused in [
        ("bag_auto", grid, ["lstm_hidden", "latent"]),
        ("bag_auto", cont, ["latent"]),
        ("greedy_mix", grid, ["lstm_hidden", "latent"]),
        ("policy_mix", grid, ["latent"]),
        ("lstm_dec", grid, []),
    ]:
        c = cfg.model_copy(
            update={"clustering": cfg.clustering.model_copy(update={"method": method})}
        )
        tune, fixed = searched_space(c, c.tuning, [unit])
        assert fixed == unused, method
        assert len(tune.lstm_hidden_sizes) == (1 if "lstm_hidden" in unused else 2)
        assert tune.latent_sizes == ((c.clustering.latent_size,) if "latent" in unused else (4, 8))


def test_best_config_is_loadable_elsewhere(tmp_path):
    cfg = config(tmp_path)
    where = tmp_path / "deep" / "out"
    where.mkdir(parents=True)
    fixed = {
        "lstm_hidden": cfg.clustering.hidden_size,
        "latent": cfg.clustering.latent_size,
    }  # not searched
    data = best_config_data(cfg, {"k": 3, "bc_width": 16, **fixed}, where)
    assert "tuning" not in data and data["name"] == "tinytune"
    assert not Path(data["gridworld"]["layout_dir"]).is_absolute()
    # only what the study's config set, and the tuned values: no other domain's defaults, and no
    # size the study held at the config's value
    assert set(data) == set(TINY) - {"tuning"}
    assert data["clustering"] == {**TINY["clustering"], "k": 3} and data["bc"] == {
        **TINY["bc"],
        "hidden_size": 16,
    }
    (where / "best.yaml").write_text(yaml.safe_dump(data))
    back = load_config(where / "best.yaml")
    assert back.clustering.k == 3 and back.bc.hidden_size == 16
    assert back.gridworld.layout_dir == cfg.gridworld.layout_dir
    assert back.pbtg == cfg.pbtg and back.ranking == cfg.ranking


# Optuna's replay of a file that is not its journal ended in a 37-line traceback (KeyError,
# TypeError, an assert), and a single line that is not JSON was skipped and then appended to.
@pytest.mark.parametrize(
    "text, line, words",
    [
        (b"name: tiny\nseed: 0\n", 1, "not JSON (Expecting value): 'name: tiny'"),
        (b'{"a": 1}\n', 1, "op_code None is not one of Optuna's journal operations (0..10)"),
        (b"[1,2]\n", 1, "[1, 2] is not a JSON object"),
        (
            b'{"op_code": 99, "worker_id": "x"}\n',
            1,
            "op_code 99 is not one of Optuna's journal operations",
        ),
        (b'{"op_code": 0}\n', 1, "Optuna cannot replay it: KeyError('study_name')"),
        (b"hello", 1, "cut off, no newline at its end"),
        (b"\xff\xfe" * 50 + b"\n", 1, "not JSON (UnicodeDecodeError)"),
        (b"[" * 100_000 + b"\n", 1, "not JSON (RecursionError)"),
        ("journal", 2, "not JSON (Expecting value): 'oops'"),  # a bad line inside a real journal
        ("journal+cut", 6, "cut off, no newline at its end"),  # a driver stopped mid-append
    ],
)
def test_a_storage_file_that_is_not_an_optuna_journal_is_refused_untouched(
    tmp_path, capsys, text, line, words
):
    target = tmp_path / "victim.log"
    if text == "journal":
        lines = real_journal(tmp_path / "real.log").splitlines(keepends=True)
        text = b"".join([lines[0], b"oops\n", *lines[1:]])
    elif text == "journal+cut":
        text = real_journal(tmp_path / "real.log") + b'{"op_code": 4, "wor'
        assert text.count(b"\n") == 5
    target.write_bytes(text)
    with pytest.raises(DataError, match=r"not an Optuna journal \(line ") as raised:
        open_storage(str(target), TuneConfig())
    assert f"(line {line}: " in str(raised.value) and words in str(raised.value)
    assert len(str(raised.value)) < 400

    code, err = tune_cli(tmp_path, capsys, "--optuna-storage", str(target))
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(
        f"pcpg: error: cannot open the Optuna journal {target}: not an Optuna journal "
        f"(line {line}: "
    )
    assert target.read_bytes() == text  # untouched: nothing appended
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["victim.log", "tiny.yaml"] + ["real.log"] * (line > 1)
    )


def test_a_real_journal_opens_and_keeps_its_study(tmp_path):
    journal = tmp_path / "j.log"
    real_journal(journal)
    storage = open_storage(str(journal), TuneConfig())
    (study,) = storage.storage.get_all_studies()
    assert study.study_name == "s" and study.user_attrs == {"pcpg.objective_key": "abc"}
    assert len(storage.storage.get_all_trials(study._study_id)) == 1
    # an empty or missing file is a new journal
    assert (
        open_storage(str(tmp_path / "new" / "j.log"), TuneConfig()).storage.get_all_studies() == []
    )


@pytest.mark.parametrize("where", ["/dev/null", "folder"])
def test_a_storage_path_that_is_not_a_regular_file_is_refused(tmp_path, capsys, where):
    path = Path(where) if where.startswith("/") else tmp_path
    code, err = tune_cli(tmp_path, capsys, "--optuna-storage", str(path))
    assert code == 2 and err.count("\n") == 1
    assert err == (
        f"pcpg: error: cannot open the Optuna journal {path}: not a regular file; give a journal "
        f"file path or an RDB URL (postgresql://user@host:5432/db)\n"
    )
    assert not (tmp_path / "work").exists()


@pytest.mark.parametrize("n", ["-3", "0", "10000000000"])
def test_n_trials_below_one_is_one_line_before_anything_starts(tmp_path, capsys, n):
    journal = tmp_path / "j.log"
    code, err = tune_cli(tmp_path, capsys, "--optuna-storage", str(journal), "--n-trials", n)
    assert code == 2
    assert err == f"pcpg: error: --n-trials must be at least 1 (and at most 10000000), got {n}\n"
    assert not journal.exists() and not (tmp_path / "work").exists()
    cfg = config(tmp_path)
    with pytest.raises(ConfigError, match="--n-trials must be at least 1"):
        tune_settings(cfg, int(n))
    assert tune_settings(cfg, 5).n_trials == 5 and tune_settings(cfg, None) == cfg.tuning


# ------------------------------------------------------------------------------ studies on Ray
@pytest.mark.slow
def test_small_study_writes_best_config_and_mlflow_children(ray_session, tmp_path, workdir):
    from mlflow import MlflowClient

    cfg = config(
        tmp_path,
        n_trials=3,
        k_range=[1, 4],
        enqueue=[{"k": 4}, {"k": 1}],
        min_cluster_fraction=0.26,
    )
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    journal = tmp_path / "journal.log"
    res = tune(
        cfg,
        storage_url=str(journal),
        workdir=workdir,
        tracking_uri=uri,
        show_progress=False,
        study_name=unique("small"),
        out=tmp_path / "out",
    )
    assert journal.is_file()
    # k=4 cannot give every cluster >= 26 % of the trajectories: pruned, with the reason kept;
    # k=1 always passes
    assert res.n_trials.get("PRUNED", 0) >= 1 and res.n_trials.get("COMPLETE", 0) >= 1
    assert sum(res.n_trials.values()) == 3
    best = load_config(res.best_config)
    assert (
        best.clustering.k == res.best_params["k"]
        and best.bc.hidden_size == res.best_params["bc_width"]
    )
    assert best.name == "tinytune"
    assert (tmp_path / "out" / "trials.csv").is_file() and (
        tmp_path / "out" / "score_vs_k.png"
    ).is_file()

    client = MlflowClient(uri)
    exp = client.get_experiment_by_name("tinytune")
    parents = client.search_runs([exp.experiment_id], filter_string="tags.`pcpg.role` = 'study'")
    assert len(parents) == 1 and parents[0].info.run_id == res.parent_run_id
    assert parents[0].info.status == "FINISHED"
    assert parents[0].data.metrics["best/score"] == pytest.approx(res.best_value)
    children = client.search_runs(
        [exp.experiment_id], filter_string=f"tags.`mlflow.parentRunId` = '{res.parent_run_id}'"
    )
    assert sorted(int(r.data.tags["pcpg.trial"]) for r in children) == [0, 1, 2]
    by_state = {r.data.tags["pcpg.trial_state"]: r for r in children}
    assert "min_cluster_fraction" in by_state["PRUNED"].data.tags["pcpg.pruned_reason"]
    done = by_state["COMPLETE"]
    m, k = done.data.metrics, int(done.data.params["k"])
    # the score is the label-free objective: accuracy minus the per-cluster penalty
    assert m["score"] == pytest.approx(m["pcpg_accuracy"] - cfg.tuning.penalty * (k - 1))
    assert 0.3 < m["pcpg_accuracy"] <= 1.0 and "E1/ari" in m
    # the study and every trial name the data they used (training and its held-out split)
    for run in [parents[0], *children]:
        inputs = client.get_run(run.info.run_id).inputs.dataset_inputs
        contexts = sorted(d.tags[0].value for d in inputs)
        assert contexts == ["evaluation", "training"], run.info.run_name
        assert {d.dataset.name for d in inputs} >= {"gridworld data"}

    # `pcpg run` of the best config in the study's folder reuses the data the study cached
    from pcpg_dist.api.run import run_experiment

    ran = run_experiment(best, workdir=workdir, track=False, show_progress=False)
    assert ran.out_dir == workdir.resolve() / "tinytune"
    assert ran.computed["data"] == 0 and ran.computed["clustering"] == 1


@pytest.mark.slow
def test_resume_continues_the_trial_count_and_retries_stale_trials(ray_session, tmp_path, workdir):
    import optuna

    cfg = config(tmp_path)
    name, journal = unique("resume"), str(tmp_path / "journal.log")
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    first = tune(
        cfg,
        storage_url=journal,
        workdir=workdir,
        tracking_uri=uri,
        show_progress=False,
        study_name=name,
        out=tmp_path / "a",
    )
    assert sum(first.n_trials.values()) == 2
    # a driver that died mid-trial leaves a RUNNING trial behind
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    study = optuna.load_study(study_name=name, storage=JournalStorage(JournalFileBackend(journal)))
    orphan = study.ask({"k": optuna.distributions.IntDistribution(2, 4)})
    second = tune(
        cfg,
        storage_url=journal,
        workdir=workdir,
        tracking_uri=uri,
        show_progress=False,
        study_name=name,
        n_trials=4,
        out=tmp_path / "b",
    )
    assert second.failed_stale == [orphan.number]
    trials = study.get_trials()
    assert [t.number for t in trials] == list(
        range(len(trials))
    )  # numbering continued, not restarted
    assert trials[orphan.number].state.name == "FAIL"
    assert "stale" in trials[orphan.number].user_attrs["error"]
    retried = [t for t in trials if t.system_attrs.get("failed_trial") == orphan.number]
    assert len(retried) == 1 and retried[0].state.name == "COMPLETE"
    assert retried[0].params["k"] == orphan.params["k"]
    assert sum(1 for t in trials if t.state.name in ("COMPLETE", "PRUNED", "FAIL")) == 4
    # one MLflow parent across both runs, one child per finished trial, none twice
    assert second.parent_run_id == first.parent_run_id
    from mlflow import MlflowClient

    client = MlflowClient(uri)
    exp = client.get_experiment_by_name("tinytune")
    kids = client.search_runs(
        [exp.experiment_id], filter_string=f"tags.`mlflow.parentRunId` = '{first.parent_run_id}'"
    )
    numbers = [int(r.data.tags["pcpg.trial"]) for r in kids]
    assert len(numbers) == len(set(numbers)) == 4
    # a changed objective must not silently mix into the same study
    with pytest.raises(ConfigError, match="other data, search space or objective"):
        tune(
            config(tmp_path, penalty=0.5),
            storage_url=journal,
            workdir=workdir,
            track=False,
            show_progress=False,
            study_name=name,
        )


@pytest.mark.slow
def test_a_raising_trial_is_recorded_failed_and_the_study_goes_on(ray_session, tmp_path, workdir):
    import optuna
    import ray.cloudpickle

    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    cfg = config(tmp_path, n_trials=3, enqueue=[{"k": 3}, {"k": 2}, {"k": 4}])
    name, journal = unique("raise"), str(tmp_path / "journal.log")
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    res = tune(
        cfg,
        storage_url=journal,
        workdir=workdir,
        tracking_uri=uri,
        show_progress=False,
        study_name=name,
        trial_fn=flaky_trial,
    )
    assert res.n_trials == {"FAIL": 1, "COMPLETE": 2}
    assert res.best_params["k"] in (2, 4)
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    trials = optuna.load_study(
        study_name=name, storage=JournalStorage(JournalFileBackend(journal))
    ).trials
    failed = [t for t in trials if t.state.name == "FAIL"]
    assert len(failed) == 1 and failed[0].params["k"] == 3
    assert failed[0].user_attrs["error"] == "RuntimeError: boom: k=3 is broken on purpose"
    from mlflow import MlflowClient

    client = MlflowClient(uri)
    exp = client.get_experiment_by_name("tinytune")
    runs = client.search_runs([exp.experiment_id], filter_string="tags.`pcpg.trial_state` = 'FAIL'")
    assert len(runs) == 1 and runs[0].info.status == "FAILED"
    assert "boom" in runs[0].data.tags["pcpg.error"]


@pytest.mark.slow
@pytest.mark.services
def test_postgres_storage_with_heartbeats_retries_a_dead_drivers_trial(
    ray_session, tmp_path, workdir
):
    import time

    import optuna
    from optuna.storages import RDBStorage

    pytest.importorskip("psycopg2")
    cfg = config(tmp_path, heartbeat_interval=1, grace_period=2)
    name = unique("pg")
    # another driver asked a trial, sent one heartbeat, and died
    url = rdb_url(POSTGRES)
    assert url.startswith("postgresql+psycopg2://")
    storage = RDBStorage(url, heartbeat_interval=1, grace_period=2)
    try:
        study = optuna.create_study(study_name=name, storage=storage, direction="maximize")
        orphan = study.ask({"k": optuna.distributions.IntDistribution(2, 4)})
        storage.record_heartbeat(orphan._trial_id)
        time.sleep(3)
        # the dead driver's study has no objective key yet: adopt it, as `pcpg tune` would
        res = tune(
            cfg,
            storage_url=POSTGRES,
            workdir=workdir,
            track=False,
            show_progress=False,
            study_name=name,
            out=tmp_path / "out",
        )
        assert res.storage == url and res.failed_stale == [orphan.number]
        trials = optuna.load_study(study_name=name, storage=url).trials
        assert trials[orphan.number].state.name == "FAIL"
        retried = [t for t in trials if t.system_attrs.get("failed_trial") == orphan.number]
        assert len(retried) == 1 and retried[0].state.name == "COMPLETE"
        # n_trials counts finished trials: the failed orphan and its completed retry
        assert res.n_trials == {"FAIL": 1, "COMPLETE": 1}
        assert load_config(res.best_config).clustering.k == res.best_params["k"]
        assert np.isfinite(res.best_value)
    finally:
        with contextlib.suppress(KeyError):
            optuna.delete_study(study_name=name, storage=url)


@pytest.mark.slow
def test_repeated_parameters_are_computed_once(ray_session, tmp_path, workdir):
    """Startup trials can draw the same point; results are deterministic, so it runs once."""
    cfg = config(tmp_path, n_trials=3, k_range=[2, 2], bc_layers_range=[1, 1], bc_widths=[8])
    res = tune(
        cfg,
        storage_url=str(tmp_path / "j.log"),
        workdir=workdir,
        track=False,
        show_progress=False,
        study_name=unique("dup"),
        out=tmp_path / "out",
    )
    import pandas as pd

    table = pd.read_csv(tmp_path / "out" / "trials.csv")
    assert res.n_trials == {"COMPLETE": 3}
    assert table["value"].nunique() == 1 and table["user_attrs_trial_seconds"].nunique() == 1


@pytest.mark.slow
def test_a_mistake_found_after_loading_the_data_leaves_no_study_behind(
    ray_session, tmp_path, workdir
):
    """`tuning.environments: [E9]` is found only once the data is loaded; the study used to be created
    and marked by then, so the corrected command was refused as "run with other data"."""
    import optuna
    import ray.cloudpickle
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    name, journal = unique("typo"), tmp_path / "journal.log"
    with pytest.raises(
        ConfigError, match=r"tuning.environments: \['E9'\] not in the data's environments \['E1'\]"
    ):
        tune(
            config(tmp_path, environments=["E9"]),
            storage_url=str(journal),
            workdir=workdir,
            track=False,
            show_progress=False,
            study_name=name,
            out=tmp_path / "out",
        )
    assert optuna.get_all_study_names(JournalStorage(JournalFileBackend(str(journal)))) == []
    assert not (tmp_path / "out").exists()
    res = tune(
        config(tmp_path),
        storage_url=str(journal),
        workdir=workdir,
        track=False,
        show_progress=False,
        study_name=name,
        out=tmp_path / "out",
        trial_fn=instant_trial,
    )
    assert res.n_trials == {"COMPLETE": 2} and res.best_value == 0.5


def test_the_trial_count_line_reads_as_words():
    """`pcpg tune` printed the raw dict: `trials {'PRUNED': 2, 'COMPLETE': 1}`."""
    import optuna
    from optuna.trial import TrialState

    from pcpg_dist.cli import trial_counts
    from pcpg_dist.orchestration.tuning import state_counts

    study = optuna.create_study(direction="maximize")
    for state in (TrialState.PRUNED, TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL):
        trial = study.ask()
        study.tell(trial, 0.5 if state == TrialState.COMPLETE else None, state=state)
    assert trial_counts(state_counts(study)) == "1 complete, 2 pruned, 1 failed"
    assert trial_counts({}) == "none"


@pytest.mark.slow
def test_an_extended_study_draws_new_points(ray_session, tmp_path, workdir):
    """`--n-trials` more on an existing study re-seeded the sampler as the first call had: its first
    draws repeated the first call's trials, answered from their results (budget spent, nothing new)."""
    cfg = config(
        tmp_path, n_startup_trials=10
    )  # both calls draw at random (as while trials are pruned)
    name, journal = unique("extend"), str(tmp_path / "journal.log")
    first = tune(
        cfg, storage_url=journal, workdir=workdir, track=False, show_progress=False, study_name=name
    )
    # a study other than NAME-tune writes to a folder of its own (a second study overwrote the first's)
    assert first.out_dir == Path(workdir).resolve() / "tinytune" / "tuning" / name
    assert (first.out_dir / "best_config.yaml").is_file()
    tune(
        cfg,
        storage_url=journal,
        workdir=workdir,
        track=False,
        show_progress=False,
        study_name=name,
        n_trials=4,
        out=tmp_path / "b",
    )
    import optuna
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    trials = optuna.load_study(
        study_name=name, storage=JournalStorage(JournalFileBackend(journal))
    ).get_trials()
    assert sum(first.n_trials.values()) == 2 and len(trials) == 4
    assert [t.params for t in trials[2:]] != [t.params for t in trials[:2]]
    assert not all("duplicate_of" in t.user_attrs for t in trials[2:])


@pytest.mark.slow
def test_a_study_where_no_trial_completes_marks_its_mlflow_run_failed(
    ray_session, tmp_path, workdir
):
    from mlflow import MlflowClient

    cfg = config(
        tmp_path, n_trials=1, k_range=[4, 4], min_cluster_fraction=0.26
    )  # k = 4: always pruned
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    with pytest.raises(DataError, match="no trial completed"):
        tune(
            cfg,
            storage_url=str(tmp_path / "journal.log"),
            workdir=workdir,
            tracking_uri=uri,
            show_progress=False,
            study_name=unique("none"),
            out=tmp_path / "out",
        )
    client = MlflowClient(uri)
    runs = client.search_runs([client.get_experiment_by_name("tinytune").experiment_id])
    roots = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    assert len(roots) == 1 and roots[0].info.status == "FAILED"  # it stayed RUNNING


def test_an_optuna_storage_of_the_wrong_kind_says_what_is_allowed(tmp_path, capsys):
    """`--optuna-storage http://HOST:PORT` (the MLflow server's URL, say) said only "Can't load
    plugin: sqlalchemy.dialects:http"."""
    code, err = tune_cli(tmp_path, capsys, "--optuna-storage", "http://127.0.0.1:5000")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "takes a journal file path or a database URL (postgresql://USER@HOST:5432/DB)" in err


def test_a_study_name_becomes_one_safe_folder():
    from pcpg_dist.orchestration.tuning import study_folder

    assert study_folder("probe-k34") == "probe-k34"
    for name in ("../x", "a/b", "..", "x" * 200, "é"):
        folder = study_folder(name)
        assert "/" not in folder and folder not in (".", "..") and len(folder) <= 80, folder
    assert study_folder("a/b") != study_folder("a:b")  # made safe alike, told apart by the hash
