"""A third-party domain package (tests/plugin_domain, `pcpg-corridor`) installed and run by `pcpg`.

The package is built and installed by uv into a private site folder that only this module puts on
``sys.path`` (and the end-to-end run on ``PYTHONPATH``), so nothing else in the session, and no
other test run sharing the virtual environment, ever sees the plugin. ``importlib.metadata`` reads
entry points from every ``*.dist-info`` on the path at call time, exactly as for a package in
site-packages, so pcpg finds it through the entry-point group alone.
"""

from __future__ import annotations

import importlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from pcpg_dist.cli import main
from pcpg_dist.domains import registry
from pcpg_dist.domains.base import Unit

PACKAGE = Path(__file__).resolve().parents[1] / "plugin_domain"
TINY = {
    "name": "corridor-e2e",
    "domain": "corridor",
    "seed": 0,
    "seeds": [0, 1],
    "corridor": {"length": 12, "trajectories_per_style": 60, "noise_max": 0.2},
    "clustering": {"k": 3, "pretrain_epochs": 6, "dec_epochs": 2},
    "ranking": {"ps": [1.0, 0.5]},
    "bc": {"epochs": 300, "hidden_size": 16},
    "evaluation": {"rollouts_per_policy": 10, "corruption_levels": [0.0, 1.0], "max_steps": 40},
}


def _uv() -> str:
    uv = os.environ.get("UV") or shutil.which("uv")  # `uv run` sets UV to its own binary
    if uv is None:
        pytest.fail("installing the plugin package needs uv on PATH (the project venv has no pip)")
    return uv


def install(package: Path, site: Path) -> None:
    """Build ``package`` with its own build backend and install it into ``site``: from uv's cache
    when hatchling is there (no network), else from the index."""
    cmd = [
        _uv(),
        "pip",
        "install",
        "--quiet",
        "--python",
        sys.executable,
        "--target",
        str(site),
        "--no-deps",
        str(package),
    ]
    done = subprocess.run([*cmd, "--offline"], capture_output=True, text=True, timeout=300)
    if done.returncode != 0:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if done.returncode != 0:
        pytest.fail(f"cannot install {package}:\n{done.stderr}")


@pytest.fixture(scope="module")
def corridor_site(tmp_path_factory):
    """The installed plugin: (site folder, names registered before); off sys.path afterwards."""
    before = registry.names()
    site = tmp_path_factory.mktemp("site")
    install(PACKAGE, site)
    sys.path.insert(0, str(site))
    importlib.invalidate_caches()
    yield site, before
    sys.path.remove(str(site))
    importlib.invalidate_caches()
    registry._loaded.pop("corridor", None)  # the registry caches loaded domains; forget ours
    for module in [m for m in sys.modules if m.split(".")[0] == "pcpg_corridor"]:
        del sys.modules[module]


def write_config(folder: Path, **changes) -> Path:
    cfg = {**TINY, **changes}
    path = folder / "corridor.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def run_cli(capsys, *argv: str) -> tuple[int, list[str]]:
    code = main(list(argv))
    return code, capsys.readouterr().err.strip().splitlines()


def test_entry_point_registers_the_domain(corridor_site):
    _, before = corridor_site
    assert "corridor" not in before
    names = registry.names()
    assert names[: len(before)] == before and "corridor" in names
    assert registry.target("corridor") == "pcpg_corridor:CorridorDomain"
    domain = registry.get("corridor")
    assert domain.name == "corridor" and type(domain).__module__ == "pcpg_corridor.domain"


def test_unknown_domain_lists_the_plugin(corridor_site, capsys, tmp_path):
    cfg = write_config(tmp_path, domain="corridr")
    code, err = run_cli(capsys, "run", str(cfg), "--no-tracking", "--workdir", str(tmp_path / "w"))
    assert code == 2 and len(err) == 1
    assert "unknown domain 'corridr'" in err[0] and "did you mean 'corridor'?" in err[0]
    registered = err[0].split("registered: ")[1].split(" (and ")[0].split(", ")
    assert {"gridworld", "mario", "corridor"} <= set(registered)
    assert not (tmp_path / "w").exists()


@pytest.mark.parametrize(
    ("section", "key", "says"),
    [
        ({"length": 3}, "corridor.length", "greater than or equal to 10"),
        (
            {"lenght": 12},
            "corridor.lenght",
            "not a setting of section 'corridor'; did you mean 'corridor.length'?",
        ),
        ({"noise_max": "lots"}, "corridor.noise_max", "valid number"),
        ({"length": 12, "max_steps": 5}, "corridor", "shorter than the explorer's route (17 steps"),
    ],
)
def test_bad_plugin_setting_names_the_key(corridor_site, capsys, tmp_path, section, key, says):
    cfg = write_config(tmp_path, corridor=section)
    code, err = run_cli(capsys, "run", str(cfg), "--no-tracking", "--workdir", str(tmp_path / "w"))
    assert code == 2 and len(err) == 1
    # one key: "key 'corridor.x'"; a check across the section's keys: "section 'corridor'", as for
    # a built-in domain's section
    where = f"key '{key}'" if "." in key else f"section '{key}'"
    assert where in err[0] and says in err[0]
    assert not (tmp_path / "w").exists()


def test_settings_and_data_through_the_seam(corridor_site, tmp_path):
    """The YAML section reaches the plugin's settings model; its data is seeded and well formed."""
    from pcpg_dist.config import load_config

    cfg = load_config(write_config(tmp_path))
    assert type(cfg.settings).__name__ == "CorridorSettings"
    assert (cfg.settings.length, cfg.settings.trajectories_per_style) == (12, 60)
    domain = cfg.domain_object
    first, again = domain.generate(cfg), domain.generate(cfg)
    assert list(first) == ["L12"]
    ds = first["L12"]
    assert ds.domain == "corridor" and ds.n_trajectories == 180 and ds.valid.dtype == bool
    np.testing.assert_array_equal(np.bincount(ds.styles), [60, 60, 60])
    np.testing.assert_array_equal(ds.actions, again["L12"].actions)
    np.testing.assert_array_equal(ds.epsilon, again["L12"].epsilon)
    assert ds.epsilon.min() >= 0.0 and ds.epsilon.max() <= 0.2 and ds.success.all()
    final = ds.states[ds.offsets[1:] - 1]
    # what tells the styles apart: coins taken by collectors, the left end seen by explorers
    coins, left_end = final[:, 1:3].mean(axis=1), final[:, 3]
    assert coins[ds.styles == 1].mean() > 0.9 and coins[ds.styles != 1].mean() < 0.2
    assert left_end[ds.styles == 2].all() and left_end[ds.styles == 0].mean() < 0.1
    seeded = load_config(write_config(tmp_path, seed=1))
    assert domain.data_key(seeded) != domain.data_key(cfg)
    assert not np.array_equal(domain.generate(seeded)["L12"].epsilon, ds.epsilon)


@pytest.mark.slow
def test_pcpg_run_end_to_end(corridor_site, tmp_path):
    """`pcpg run` in a fresh process: Ray's workers find the plugin through PYTHONPATH alone."""
    site, _ = corridor_site
    cfg = write_config(tmp_path)
    path = os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))
    env = {
        **os.environ,
        "PYTHONPATH": path,
        "RAY_AUTH_MODE": "disabled",
        "RAY_ENABLE_UV_RUN_RUNTIME_ENV": "0",
    }
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "pcpg_dist.cli",
            "run",
            str(cfg),
            "--no-tracking",
            "--workdir",
            str(tmp_path / "runs"),
            "--quiet",
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=540,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    summary = tmp_path / "runs" / "corridor-e2e" / "summary"
    for name in ("metrics.json", "accuracy_vs_p.csv", "clustering.csv", "run.json"):
        assert (summary / name).is_file(), name
    assert (summary / "L12" / "rollouts.csv").is_file()
    m = json.loads((summary / "metrics.json").read_text())

    # three clearly different styles: Step A recovers them
    assert m["clustering/accuracy"] > 0.8
    # PCPG imitates far better than chance, and better than one agent for all styles once the
    # top half is kept (the styles act differently in the same states)
    assert m["pcpg/accuracy/p1"] > m["random/accuracy/p1"] + 0.3
    assert m["pcpg/accuracy/p0.5"] > m["baseline/accuracy/p0.5"] + 0.1
    # each cluster's agent walks its style's noiseless route (rusher 5, collector 15, explorer 17)
    from pcpg_corridor.game import Corridor

    routes = sorted(Corridor(12).route_length(style) for style in range(3))
    assert sorted(m[f"rollout/length/k{c}/p1"] for c in range(3)) == pytest.approx(routes, abs=1.0)
    run = json.loads((summary / "run.json").read_text())
    assert run["config"]["domain"] == "corridor" and run["config"]["corridor"]["length"] == 12


# --------------------------------------------------------------------------- broken plugins
# A third party's domain that breaks the contract of docs/writing-a-domain.md: the corridor with
# one method replaced. pcpg checks what each method returns where it receives it, and turns an
# exception raised inside a plugin's method into one line naming the domain and the method.


def broken_corridor(**methods):
    """The corridor domain with ``methods`` replaced (a subclass, as a plugin author writes one)."""
    from pcpg_corridor import CorridorDomain

    return type("BrokenCorridor", (CorridorDomain,), methods)()


def raising(exc: Exception):
    def method(*args, **kwargs):
        raise exc

    return method


def corridor_units(test_idx):
    def units(self, cfg, datasets):
        return [Unit(env, ds, np.asarray(test_idx)) for env, ds in datasets.items()]

    return units


def _generated(self, cfg, show_progress=True):
    from pcpg_corridor import CorridorDomain

    return CorridorDomain.generate(self, cfg, show_progress)


BEFORE_CLUSTERING = {
    "generate-empty": (
        {"generate": lambda self, cfg, show_progress=True: {}},
        "generate returned an empty dict; it must return a non-empty dict of environment "
        "name -> Dataset",
    ),
    "generate-list": (
        {"generate": lambda self, cfg, show_progress=True: list(_generated(self, cfg).values())},
        "generate returned a list; it must return a non-empty dict",
    ),
    "generate-none": (
        {"generate": lambda self, cfg, show_progress=True: None},
        "generate returned None; it must return a non-empty dict",
    ),
    "generate-array": (
        {"generate": lambda self, cfg, show_progress=True: {"L12": np.zeros(3)}},
        "generate returned a ndarray for 'L12'; it must return a non-empty dict",
    ),
    "generate-same-env": (
        {
            "generate": lambda self, cfg, show_progress=True: {
                "a": _generated(self, cfg)["L12"],
                "b": _generated(self, cfg)["L12"],
            }
        },
        "generate returned two datasets of environment 'L12' (keys 'a' and 'b')",
    ),
    "generate-raises": (
        {"generate": raising(RuntimeError("simulator crashed\nat step 7"))},
        "generate raised RuntimeError: simulator crashed",
    ),
    "units-out-of-range": (
        {"units": corridor_units([0, 5, 999])},
        "units returned unit 'L12' with test_idx 999, outside 0..179 (its dataset holds "
        "180 trajectories)",
    ),
    "units-negative": ({"units": corridor_units([-1, 3])}, "test_idx -1, outside 0..179"),
    "units-floats": (
        {"units": corridor_units([0.5, 3.0])},
        "dtype float64; it must be a 1-D array of trajectory positions (integers)",
    ),
    "units-repeated": ({"units": corridor_units([3, 3])}, "test_idx naming a trajectory twice"),
    "units-all-held-out": (
        {"units": corridor_units(np.arange(180))},
        "all 180 trajectories held out; at least one must be left for training",
    ),
    "units-cluster-input": (
        {
            "units": lambda self, cfg, datasets: [
                Unit("L12", datasets["L12"], np.arange(5), datasets["L12"].subset(np.arange(9)))
            ]
        },
        "unit 'L12' with 9 trajectories as its cluster_input; it must be a Dataset of the "
        "same 180 trajectories",
    ),
    "units-same-name": (
        {"units": lambda self, cfg, datasets: [Unit("L12", datasets["L12"], np.arange(5))] * 2},
        "units returned a unit named 'L12' at position 1; every unit needs its own",
    ),
    "units-none": (
        {"units": lambda self, cfg, datasets: None},
        "units returned None; it must return a non-empty list of Unit",
    ),
    "units-raises": ({"units": raising(KeyError("L13"))}, "units raised KeyError: 'L13'"),
    "score-raises": (
        {"score": raising(ValueError("no skill column"))},
        "score raised ValueError: no skill column",
    ),
    "score-function-raises": (
        {"score": lambda self, cfg: raising(ZeroDivisionError("division by zero"))},
        "score's function raised ZeroDivisionError: division by zero",
    ),
    "score-not-callable": (
        {"score": lambda self, cfg: np.ones(180)},
        "score returned a ndarray; it must return None or a function",
    ),
    "score-wrong-shape": (
        {"score": lambda self, cfg: lambda ds: np.ones(3)},
        "its score function returned shape (3,) for L12; it must return one number per "
        "trajectory, shape (180,)",
    ),
    "score-strings": (
        {"score": lambda self, cfg: lambda ds: ["high"] * ds.n_trajectories},
        "score's function returned a list that does not convert to floats",
    ),
    "hooks-raises": (
        {"hooks": raising(FileNotFoundError(2, "No such file", "levels/L12.txt"))},
        "hooks raised FileNotFoundError: [Errno 2] No such file: 'levels/L12.txt'",
    ),
    "hooks-dict": (
        {"hooks": lambda self, cfg, unit: {"rollout": None}},
        "hooks returned a dict for unit 'L12'; it must return None or a DomainHooks",
    ),
}


@pytest.mark.parametrize("fault", list(BEFORE_CLUSTERING))
def test_broken_plugin_fails_in_one_line_before_clustering(
    corridor_site, ray_session, capsys, tmp_path, monkeypatch, fault
):
    """A plugin whose generate, units, score or hooks is broken stops `pcpg run` with one line
    naming the domain, the method and what it returned (or raised), before any Ray task starts:
    no clustering, nothing written but the generated data's cache entry."""
    from pcpg_dist.orchestration.runner import Batch

    methods, says = BEFORE_CLUSTERING[fault]
    monkeypatch.setitem(registry._loaded, "corridor", broken_corridor(**methods))
    stages = []
    monkeypatch.setattr(
        Batch, "run_jobs", lambda self, stage, *a, **k: stages.append(stage.description) or 0
    )
    work = tmp_path / "w"
    code, err = run_cli(
        capsys, "run", str(write_config(tmp_path)), "--no-tracking", "--workdir", str(work)
    )
    assert (code, len(err)) == (2, 1), err
    who = "domain 'corridor': "  # every fault names the domain (the score's shape did not)
    assert err[0].startswith(f"pcpg: error: {who}") and says in err[0], err[0]
    assert stages == []  # failed before Step A: no task of any stage was submitted
    assert not (work / "corridor-e2e" / "cache" / "cluster").exists()
    if fault.startswith("generate"):  # checked before the data is cached: nothing written at all
        assert not work.exists()


@pytest.fixture(scope="module")
def corridor_trained(corridor_site, tmp_path_factory):
    """A tiny corridor unit clustered and trained in-process: (cfg, unit, labels, trained)."""
    from pcpg_dist.config import load_config
    from pcpg_dist.domains import contract
    from pcpg_dist.pipeline import cluster_unit, plan_unit
    from pcpg_dist.stages.bc import train_plan

    small = {
        "corridor": {"length": 12, "trajectories_per_style": 8, "noise_max": 0.2},
        "seeds": [0],
        "ranking": {"ps": [1.0]},
        "bc": {"epochs": 3, "hidden_size": 8},
        "clustering": {"k": 3, "pretrain_epochs": 1, "dec_epochs": 1},
        "evaluation": {"rollouts_per_policy": 2, "corruption_levels": [0.0], "max_steps": 20},
    }
    cfg = load_config(write_config(tmp_path_factory.mktemp("cfg"), **small))
    (unit,) = contract.units(cfg, contract.generate(cfg, show_progress=False))
    clustering = cluster_unit(unit, cfg.clustering, cfg.seed, ceiling=False)
    trained = train_plan(plan_unit(unit, clustering.labels, cfg), cfg.bc)
    return cfg, unit, clustering.labels, trained


def _rollout_returning(value):
    def hooks(self, cfg, unit):
        from pcpg_dist.domains.base import DomainHooks

        return DomainHooks(rollout=lambda policy, n, rng: value(n))

    return hooks


def _short_rollout(self, cfg, unit):
    from pcpg_corridor.game import Corridor, rollout_fn

    from pcpg_dist.domains.base import DomainHooks

    real = rollout_fn(Corridor(12), cfg.evaluation.max_steps)
    return DomainHooks(rollout=lambda policy, n, rng: real(policy, n - 1, rng))


IN_EVALUATION = {
    "extras-str": (
        {"extras": lambda self, *a: {"x": "abc"}},
        "extras returned 'x': 'abc' for unit 'L12'; it must return a dict of metric name (str) -> "
        "finite float",
    ),
    "extras-nan": ({"extras": lambda self, *a: {"x": float("nan")}}, "extras returned 'x': nan"),
    "extras-list": ({"extras": lambda self, *a: [1.0]}, "extras returned a list for unit 'L12'"),
    "extras-raises": (
        {"extras": raising(IndexError("list index out of range"))},
        "extras raised IndexError: list index out of range",
    ),
    "rollout-dict": (
        {"hooks": _rollout_returning(lambda n: {"lengths": [5] * n})},
        "the rollout hook returned a dict; it must return a Dataset of the 2 episodes asked for",
    ),
    "rollout-none": (
        {"hooks": _rollout_returning(lambda n: None)},
        "the rollout hook returned None",
    ),
    "rollout-short": (
        {"hooks": _short_rollout},
        "the rollout hook returned a Dataset of 1 episode(s); it must return a Dataset of the 2 "
        "episodes asked for",
    ),
    "rollout-raises": (
        {"hooks": _rollout_returning(raising(OSError("simulator died")))},
        "the rollout hook raised OSError: simulator died",
    ),
}


@pytest.mark.parametrize("fault", list(IN_EVALUATION))
def test_broken_plugin_in_the_evaluation_is_one_line(
    corridor_trained, monkeypatch, tmp_path, fault
):
    """extras and rollouts run inside the evaluation (a Ray task in `pcpg run`, whose PcpgError
    reaches the CLI as its one line): what they return is checked where the evaluation gets it."""
    from pcpg_dist.common.errors import DomainError
    from pcpg_dist.pipeline import evaluate_unit

    cfg, unit, labels, trained = corridor_trained
    methods, says = IN_EVALUATION[fault]
    monkeypatch.setitem(registry._loaded, "corridor", broken_corridor(**methods))
    with pytest.raises(DomainError) as raised:
        evaluate_unit(unit, labels, trained, cfg, tmp_path)
    message = str(raised.value)
    assert "\n" not in message and message.startswith("domain 'corridor': ") and says in message, (
        message
    )


def test_good_extras_and_rollouts_pass_through(corridor_trained, monkeypatch, tmp_path):
    """The checks let a well-behaved plugin's metrics through as floats (numpy numbers too)."""
    from pcpg_dist.pipeline import evaluate_unit

    cfg, unit, labels, trained = corridor_trained
    extras = {
        "extras": lambda self, *a: {"mine/count": np.int64(3), "mine/share": np.float32(0.25)}
    }
    monkeypatch.setitem(registry._loaded, "corridor", broken_corridor(**extras))
    metrics = evaluate_unit(unit, labels, trained, cfg, tmp_path)
    assert metrics["mine/count"] == 3.0 and metrics["mine/share"] == 0.25
    assert type(metrics["mine/count"]) is float
    assert sorted(
        k for k in metrics if k.startswith("rollout/length/k")
    )  # the corridor's rollouts ran


def test_a_built_in_domains_exception_keeps_its_traceback():
    """Only a plugin's exceptions become one line: in a built-in domain it is a bug in pcpg-dist."""
    from pcpg_dist.common.errors import DomainError
    from pcpg_dist.domains import contract
    from pcpg_dist.domains.base import Domain

    builtin = type("Builtin", (Domain,), {"__module__": "pcpg_dist.domains.fake", "name": "fake"})()
    plugin = type("Plugin", (Domain,), {"name": "fake"})()
    with pytest.raises(ZeroDivisionError), contract.calling(builtin, "generate"):
        1 / 0  # noqa: B018
    says = "^domain 'fake': generate raised ZeroDivisionError: division by zero$"
    with pytest.raises(DomainError, match=says), contract.calling(plugin, "generate"):
        1 / 0  # noqa: B018


def test_a_plugin_check_config_raising_anything_is_one_line(
    corridor_site, capsys, tmp_path, monkeypatch
):
    """check_config may raise ValueError or a pcpg error; anything else was a traceback at load."""
    monkeypatch.setitem(
        registry._loaded,
        "corridor",
        broken_corridor(check_config=raising(OSError(13, "Permission denied", "/srv/levels"))),
    )
    code, err = run_cli(
        capsys,
        "run",
        str(write_config(tmp_path)),
        "--no-tracking",
        "--workdir",
        str(tmp_path / "w"),
    )
    assert (code, len(err)) == (2, 1), err
    assert (
        "domain 'corridor': check_config raised PermissionError: [Errno 13] Permission denied: "
        "'/srv/levels'" in err[0]
    ), err[0]
    assert not (tmp_path / "w").exists()


def test_an_entry_point_that_is_not_a_domain_says_so(monkeypatch):
    """An entry point naming a plain class failed later with 'check_config raised AttributeError'."""
    from pcpg_dist.common.errors import ConfigError

    monkeypatch.setitem(registry.BUILTIN, "notdomain", "collections:OrderedDict")
    with pytest.raises(ConfigError) as e:
        registry.get("notdomain")
    assert str(e.value) == (
        "domain 'notdomain': collections:OrderedDict is <class 'collections.OrderedDict'>, "
        "not a pcpg_dist.domains.base.Domain (subclass of it, or an instance); "
        "docs/writing-a-domain.md shows one"
    )
    assert "notdomain" not in registry._loaded
