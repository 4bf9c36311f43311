"""gridworld.random_layouts: N style-distinct random layouts, deterministic in the seed."""

from __future__ import annotations

import time
import warnings

import numpy as np
import pytest
import yaml

from pcpg_dist.common.errors import ConfigError
from pcpg_dist.config import load_config
from pcpg_dist.domains.gridworld import layout as gw
from pcpg_dist.domains.gridworld.domain import GridWorldDomain, gridworld_layout, gridworld_layouts


def test_same_seed_same_layouts_and_a_prefix_does_not_depend_on_count():
    a = gw.random_layouts(6, seed=7)
    b = gw.random_layouts(3, seed=7)
    assert [lt.grid for lt in a[:3]] == [lt.grid for lt in b]
    assert [lt.name for lt in a] == ["R0000", "R0001", "R0002", "R0003", "R0004", "R0005"]
    other = gw.random_layouts(3, seed=8)
    assert all(x.grid != y.grid for x, y in zip(b, other, strict=True))
    assert len({lt.grid for lt in a}) == 6  # no two layouts of one family alike


def test_every_layout_passes_the_loaders_checks_and_styles_are_distinct():
    for lt in gw.random_layouts(12, seed=3):
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # the loader warns when styles are not distinct
            again = gw.parse_layout(lt.text(), name=lt.name)
        assert again.grid == lt.grid and lt.width == lt.height == 10
        assert gw.style_problem(lt) is None
        t = lt.tables
        routes = gw.optimal_routes(lt)
        assert len({tuple(np.asarray(r) // 4) for r in routes}) == 4  # four distinct cell routes
        for r, route in enumerate(routes):
            assert t.goal[route[-1]]
            assert tuple(t.features[route[-1], 2:].astype(int)) == gw.SIGNATURES[r]


def test_generation_is_fast():
    # Issue 16 draws 80 layouts per run: the generator must stay well under a second per layout.
    start = time.perf_counter()
    gw.random_layouts(10, seed=11)
    assert (time.perf_counter() - start) / 10 < 0.5


def _config(tmp_path, gridworld: dict):
    path = tmp_path / "exp.yaml"
    path.write_text(yaml.safe_dump({"name": "r", "domain": "gridworld", "gridworld": gridworld}))
    return load_config(path)


def test_config_names_units_and_domain_uses_the_generated_layouts(tmp_path):
    cfg = _config(tmp_path, {"random_layouts": {"count": 3, "seed": 5}, "layout_dir": "nowhere"})
    assert cfg.gridworld.units == ["R0000", "R0001", "R0002"]
    layouts = gridworld_layouts(cfg)
    assert [lt.grid for lt in layouts] == [lt.grid for lt in gw.random_layouts(3, 5)]
    assert gridworld_layout(cfg, "R0002").grid == layouts[2].grid
    key = GridWorldDomain().data_key(cfg)
    # keyed by what draws them (count, seed, the generator's code and numpy), not by their text:
    # the driver never draws a random family
    assert key[3] == ["R0000", "R0001", "R0002"] and key[4][:3] == ["random", 3, 5]
    other = _config(tmp_path, {"random_layouts": {"count": 3, "seed": 6}})
    assert GridWorldDomain().data_key(other) != key


def test_the_driver_draws_no_random_layout_and_a_generator_change_regenerates(
    tmp_path, monkeypatch
):
    from pcpg_dist.domains.gridworld import domain

    cfg = _config(tmp_path, {"random_layouts": {"count": 4, "seed": 5}})
    drawn: list = []
    real = gw.random_layout
    monkeypatch.setattr(gw, "random_layout", lambda *a, **k: drawn.append(a) or real(*a, **k))
    domain._random_layout.cache_clear()
    key = GridWorldDomain().data_key(cfg)
    assert drawn == []  # planning the data costs nothing per layout
    data = GridWorldDomain().generate(
        cfg.model_copy(
            update={
                "pbtg": cfg.pbtg.model_copy(
                    update={"episodes": 50, "trajectories_per_style": 2, "dataset_per_style": 2}
                )
            }
        ),
        show_progress=False,
    )
    assert list(data) == ["R0000", "R0001", "R0002", "R0003"]
    assert {a[0] for a in drawn} == {(5, i) for i in range(4)}  # each drawn where it is used
    # a change to the generator's code (or numpy) is a new key, so old data is not reused
    domain._generator_digest.cache_clear()
    monkeypatch.setattr("numpy.__version__", "0.0-other")
    assert GridWorldDomain().data_key(cfg) != key
    domain._generator_digest.cache_clear()


@pytest.mark.parametrize(
    "section, needle",
    [
        ({"random_layouts": {"count": 0, "seed": 1}}, "gridworld.random_layouts.count"),
        ({"random_layouts": {"count": 2, "seed": -1}}, "gridworld.random_layouts.seed"),
        ({"random_layouts": {"count": 2}, "environments": ["E1"]}, "not both"),
        ({"random_layouts": {"count": 2, "sed": 1}}, "sed"),
    ],
)
def test_bad_random_layouts_give_one_line(tmp_path, section, needle):
    with pytest.raises(ConfigError) as e:
        _config(tmp_path, section)
    assert needle in str(e.value) and "\n" not in str(e.value)
