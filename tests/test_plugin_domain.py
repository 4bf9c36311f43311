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

PACKAGE = Path(__file__).resolve().parent / "plugin_domain"
TINY = {
    "name": "corridor-e2e", "domain": "corridor", "seed": 0, "seeds": [0, 1],
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
    cmd = [_uv(), "pip", "install", "--quiet", "--python", sys.executable, "--target", str(site),
           "--no-deps", str(package)]
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


@pytest.mark.parametrize(("section", "key", "says"), [
    ({"length": 3}, "corridor.length", "greater than or equal to 10"),
    ({"lenght": 12}, "corridor.lenght", "not a setting of section 'corridor'; did you mean 'corridor.length'?"),
    ({"noise_max": "lots"}, "corridor.noise_max", "valid number"),
    ({"length": 12, "max_steps": 5}, "corridor", "shorter than the explorer's route (17 steps"),
])
def test_bad_plugin_setting_names_the_key(corridor_site, capsys, tmp_path, section, key, says):
    cfg = write_config(tmp_path, corridor=section)
    code, err = run_cli(capsys, "run", str(cfg), "--no-tracking", "--workdir", str(tmp_path / "w"))
    assert code == 2 and len(err) == 1
    assert f"key '{key}'" in err[0] and says in err[0]
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
    env = {**os.environ, "PYTHONPATH": path, "RAY_AUTH_MODE": "disabled",
           "RAY_ENABLE_UV_RUN_RUNTIME_ENV": "0"}
    done = subprocess.run([sys.executable, "-m", "pcpg_dist.cli", "run", str(cfg), "--no-tracking",
                           "--workdir", str(tmp_path / "runs"), "--quiet"],
                          capture_output=True, text=True, env=env, timeout=540, cwd=tmp_path)
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
    assert run["config"]["domain"] == "corridor" and run["config"]["plugin"]["length"] == 12
