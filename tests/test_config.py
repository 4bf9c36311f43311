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
