"""A config holds the core sections and its own domain's: each domain registers its sections the
same way (``Domain.sections``), and another domain's settings never change a config's hash."""

from __future__ import annotations

import pickle
from pathlib import Path

import pytest

from pcpg_dist.common.errors import ConfigError
from pcpg_dist.config import load_config, parse_config
from pcpg_dist.domains import registry
from pcpg_dist.domains.minidungeons.settings import MiniDungeonsConfig

EXPERIMENTS = Path(__file__).resolve().parents[2] / "experiments"


@pytest.mark.parametrize("name", ["quick.yaml", "minidungeons_paper.yaml", "mario.yaml"])
def test_a_dumped_config_parses_back_to_itself_and_pickles(name):
    cfg = load_config(EXPERIMENTS / name)
    dumped = cfg.model_dump(mode="json")
    assert set(dumped) - {"name", "domain", "seed", "seeds", "clustering", "ranking", "bc"} - {
        "evaluation",
        "runner",
        "tuning",
    } == set(cfg.domain_object.config_sections())
    assert parse_config(dumped) == cfg
    back = pickle.loads(pickle.dumps(cfg))
    assert back == cfg and type(back) is type(cfg) and back.hash() == cfg.hash()


def test_builtin_sections_come_from_light_settings_modules():
    assert registry.sections("gridworld") == type(registry.get("gridworld")).section_models()
    assert list(registry.sections("gridworld")) == ["gridworld", "pbtg"]
    for name in registry.BUILTIN:
        assert registry.sections(name) == registry.get(name).section_models()


def test_another_domains_sections_are_checked_then_dropped():
    cfg = parse_config(
        {"name": "m", "domain": "mario", "minidungeons": {"runs_per_level": 3}, "plugin": {}}
    )
    assert "minidungeons" not in cfg.model_dump() and not hasattr(cfg, "minidungeons")
    assert cfg == parse_config({"name": "m", "domain": "mario"})
    with pytest.raises(ConfigError, match="key 'minidungeons.runs_per_level'"):
        parse_config({"name": "m", "domain": "mario", "minidungeons": {"runs_per_level": 0}})
    with pytest.raises(ConfigError, match="did you mean 'minidungeons'"):
        parse_config({"name": "m", "domain": "mario", "minidungeon": {}})


def test_another_domains_defaults_do_not_change_the_hash(monkeypatch):
    before = (
        parse_config({"name": "h"}).hash(),
        parse_config({"name": "h", "domain": "mario"}).hash(),
    )

    class ChangedMiniDungeons(MiniDungeonsConfig):
        """MiniDungeons' section with another default and one more setting."""

        runs_per_level: int = 11
        new_setting: int = 1

    builtin_sections = registry.sections
    monkeypatch.setattr(
        registry,
        "sections",
        lambda name: (
            {"minidungeons": ChangedMiniDungeons}
            if name == "minidungeons"
            else builtin_sections(name)
        ),
    )
    md = parse_config({"name": "h", "domain": "minidungeons"})
    assert md.minidungeons.runs_per_level == 11 and md.minidungeons.new_setting == 1
    after = (
        parse_config({"name": "h"}).hash(),
        parse_config({"name": "h", "domain": "mario"}).hash(),
    )
    assert after == before
