"""Experiment configs: strict validation with one-line errors naming key, value and what is allowed."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from pcpg_dist.config import load_config, parse_config
from pcpg_dist.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent
EXPERIMENTS = ROOT / "experiments"


def write(tmp_path: Path, data: dict) -> Path:
    (tmp_path / "gridworlds").mkdir(exist_ok=True)
    for env in ("E1", "E2"):
        (tmp_path / "gridworlds" / f"{env}.txt").write_text((EXPERIMENTS / "gridworlds" / f"{env}.txt").read_text())
    path = tmp_path / "exp.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


BASE = {"name": "t", "gridworld": {"environments": ["E1", "E2"]}}


@pytest.mark.parametrize("name", sorted(p.name for p in EXPERIMENTS.glob("*.yaml")))
def test_shipped_configs_load(name):
    cfg = load_config(EXPERIMENTS / name)
    assert cfg.name and cfg.flat()["name"] == cfg.name


def test_layout_dir_is_relative_to_the_config_file(tmp_path):
    cfg = load_config(write(tmp_path, BASE))
    assert cfg.gridworld.layout_path("E1") == (tmp_path / "gridworlds" / "E1.txt").resolve()
    assert cfg.hash() == load_config(write(tmp_path, BASE)).hash()


@pytest.mark.parametrize("patch, needle", [
    ({"bogus": 1}, "unknown key 'bogus'"),
    ({"pbtg": {"episodes": -5}}, "key 'pbtg.episodes': value -5 is not allowed — Input should be greater than or equal to 1"),
    ({"pbtg": {"noise_max": "lots"}}, "key 'pbtg.noise_max': value 'lots'"),
    ({"seeds": [1, 1]}, "key 'seeds'"),
    ({"name": "../escape"}, "key 'name': value '../escape' is not allowed"),
    ({"name": "/abs"}, "key 'name'"),
    ({"gridworld": {"environments": ["E9"]}}, "E9.txt for environment 'E9' not found"),
    ({"domain": "chess"}, "key 'domain': value 'chess'"),
])
def test_bad_values_give_one_line(tmp_path, patch, needle):
    data = {**BASE, **patch}
    with pytest.raises(ConfigError) as e:
        load_config(write(tmp_path, data))
    msg = str(e.value)
    assert needle in msg and "\n" not in msg and "exp.yaml" in msg


def test_yaml_syntax_error_names_the_line(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("name: x\nseeds: [1, 2\nother: 3\n")
    with pytest.raises(ConfigError, match=r"broken.yaml, line \d+: not valid YAML"):
        load_config(path)


def test_non_mapping_and_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="YAML mapping"):
        parse_config([1, 2])
    with pytest.raises(ConfigError, match="cannot read config"):
        load_config(tmp_path / "none.yaml")


def test_configs_are_frozen(tmp_path):
    cfg = load_config(write(tmp_path, BASE))
    with pytest.raises(ValueError):
        cfg.seed = 3  # type: ignore[misc]


# ------------------------------------------------------------------ the domain seam
def test_unknown_domain_is_one_line_listing_the_registered_names(tmp_path):
    with pytest.raises(ConfigError) as e:
        load_config(write(tmp_path, {**BASE, "domain": "grid_world"}))
    msg = str(e.value)
    assert len(msg.splitlines()) == 1 and "key 'domain'" in msg and "did you mean 'gridworld'" in msg
    for name in ("gridworld", "minidungeons", "mario", "trajectories"):
        assert name in msg


def test_trajectories_domain_needs_an_existing_path(tmp_path):
    with pytest.raises(ConfigError, match="needs trajectories.path"):
        load_config(write(tmp_path, {"name": "t", "domain": "trajectories"}))
    with pytest.raises(ConfigError, match="trajectories.path .*nope.parquet not found"):
        load_config(write(tmp_path, {"name": "t", "domain": "trajectories", "trajectories": {"path": "nope.parquet"}}))
    (tmp_path / "logs.parquet").write_bytes(b"")
    cfg = load_config(write(tmp_path, {"name": "t", "domain": "trajectories", "trajectories": {"path": "logs.parquet"}}))
    assert cfg.settings.path == str((tmp_path / "logs.parquet").resolve())  # relative to the config file


def test_a_domains_settings_are_checked_only_when_it_is_chosen(tmp_path):
    """A Mario config carries GridWorld's default layout folder, which need not exist."""
    cfg = load_config(write(tmp_path, {"name": "m", "domain": "mario", "gridworld": {"environments": ["nope"]}}))
    assert cfg.domain == "mario" and cfg.settings is cfg.mario


def test_loading_a_config_imports_no_torch_and_no_stage():
    import subprocess
    import sys

    code = ("import sys; from pcpg_dist.config import load_config; "
            f"[load_config(p) for p in {[str(p) for p in sorted(EXPERIMENTS.glob('*.yaml'))]!r}]; "
            "heavy = [m for m in ('torch', 'ray', 'mlflow', 'optuna', 'pcpg_dist.bc', 'pcpg_dist.clustering', "
            "'pcpg_dist.tuning', 'pcpg_dist.runner', 'pcpg_dist.evaluation', 'pcpg_dist.ranking') if m in sys.modules]; "
            "print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
