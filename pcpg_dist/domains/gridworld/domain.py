"""GridWorld as a registered domain: PBTG data, one unit per layout, rollouts and reward distances.

PBTG runs one Ray task per (layout, reward function); each layout is one unit with a seeded 80/20
trajectory split. The layouts simulate, so the evaluation gets rollouts, returns under every
style's reward, optimal returns and drawings (Tables 3/5, Figs. 5, 6, 8).
"""

from __future__ import annotations

from functools import cache, lru_cache
from typing import Any

from pcpg_dist.domains.base import Domain, DomainHooks, FanOut
from pcpg_dist.domains.defaults import in_process
from pcpg_dist.domains.gridworld.paper import PAPER
from pcpg_dist.domains.gridworld.settings import SECTIONS

N_STYLES = 4  # PBTG's reward functions: one style each


@lru_cache(maxsize=1024)
def _random_layout(seed: int, index: int):
    """Layout ``index`` of the random family ``seed`` (drawn where it is used: in the data and
    evaluation tasks, one each, never the whole family in the driver)."""
    from pcpg_dist.domains.gridworld.layout import random_layout, random_layout_name

    return random_layout((seed, index), name=random_layout_name(index))


@lru_cache(maxsize=1)
def _generator_digest() -> str:
    """What the random layouts are a function of besides (seed, index): the generator's code and
    numpy's random streams. In the data key instead of the layouts' text, so that the driver need
    not draw them (~13 ms a layout) and a generator change still regenerates."""
    import hashlib
    from pathlib import Path

    import numpy as np

    from pcpg_dist.domains.gridworld import layout

    code = Path(layout.__file__).read_bytes()
    return hashlib.sha256(code + np.__version__.encode()).hexdigest()[:16]


def _random_family(count: int, seed: int):
    return tuple(_random_layout(seed, i) for i in range(count))


def _random_pair(seed: int, index: int, reward_index: int, pbtg, base_seed: int):
    """:func:`~pcpg_dist.domains.gridworld.pbtg.generate_pair` for random layout ``index``."""
    from pcpg_dist.domains.gridworld.pbtg import generate_pair

    return generate_pair(_random_layout(seed, index), reward_index, pbtg, base_seed)


def gridworld_layouts(cfg):
    """The config's layouts, checked (style-distinct routes and signatures): drawn by the
    generator when ``gridworld.random_layouts`` is set, else read from the layout files."""
    rl = cfg.gridworld.random_layouts
    if rl is not None:
        return list(_random_family(rl.count, rl.seed))
    return [_file_layout(cfg, env) for env in cfg.gridworld.environments]


def _file_layout(cfg, env: str, check_styles: bool = True):
    """A layout file's layout, from the text the config captured on the driver."""
    from pcpg_dist.domains.gridworld.layout import Layout, parse_layout

    gw = cfg.gridworld
    return Layout(
        name=env,
        grid=parse_layout(
            gw.layout_text(env), name=str(gw.layout_path(env)), check_styles=check_styles
        ).grid,
    )


def gridworld_layout(cfg, unit: str):
    """One unit's layout (unchecked for style problems: the data was generated from it)."""
    rl = cfg.gridworld.random_layouts
    if rl is not None:
        return _random_layout(rl.seed, rl.names.index(unit))
    return _file_layout(cfg, unit, check_styles=False)


class GridWorldDomain(Domain):
    name = "gridworld"
    sections = SECTIONS
    paper = PAPER

    def check_config(self, cfg) -> None:
        """The settings' checks, and k against the trajectories each layout will have (the
        config fixes the count: one PBTG dataset per reward function), before any data is made."""
        from pcpg_dist.common.errors import ConfigError

        super().check_config(cfg)
        n = N_STYLES * cfg.pbtg.dataset_per_style
        if cfg.clustering.k > n:
            raise ConfigError(
                f"key 'clustering.k': {cfg.clustering.k} clusters, but each layout will have {n} "
                f"trajectories ({N_STYLES} styles x pbtg.dataset_per_style "
                f"{cfg.pbtg.dataset_per_style}); set clustering.k to at most {n}"
            )

    def data_key(self, cfg) -> list[Any]:
        gw = cfg.gridworld
        if gw.random_layouts is not None:
            layouts = ["random", gw.random_layouts.count, gw.random_layouts.seed]
            layouts.append(_generator_digest())
        else:
            layouts = [gw.layout_text(e) for e in gw.environments]
        return [self.name, cfg.seed, cfg.pbtg, gw.units, layouts]

    def generate(self, cfg, show_progress: bool = True, fan_out: FanOut = in_process):
        from pcpg_dist.domains.gridworld.pbtg import assemble_dataset, generate_pair

        rl, n = cfg.gridworld.random_layouts, N_STYLES
        if rl is not None:  # each task draws its own layout
            names = rl.names
            calls = [(rl.seed, i, r, cfg.pbtg, cfg.seed) for i in range(rl.count) for r in range(n)]
            pairs = fan_out(_random_pair, calls, "PBTG (E, R)", show_progress=show_progress)
        else:
            layouts = gridworld_layouts(cfg)
            names = [lt.name for lt in layouts]
            calls = [(lt, r, cfg.pbtg, cfg.seed) for lt in layouts for r in range(n)]
            pairs = fan_out(generate_pair, calls, "PBTG (E, R)", show_progress=show_progress)
        return {name: assemble_dataset(pairs[n * i : n * i + n]) for i, name in enumerate(names)}

    def manifest(self, cfg, datasets) -> dict[str, Any]:
        from pcpg_dist.domains.gridworld.pbtg import pair_seed

        return {
            "seed_entropy": {
                f"{env}/R{r + 1}": pair_seed(cfg.seed, env, r).entropy
                for env in datasets
                for r in range(4)
            }
        }

    def hooks(self, cfg, unit: str) -> DomainHooks:
        from pcpg_dist.domains.gridworld import layout as gw
        from pcpg_dist.domains.gridworld import play

        steps = cfg.evaluation.max_steps
        # drawn (or read) on first use, in the evaluation task: the driver asks every unit for
        # its hooks, and a random layout costs ~13 ms to draw
        layout = cache(lambda: gridworld_layout(cfg, unit))
        return DomainHooks(
            rollout=lambda policy, n, rng: play.rollout(layout(), policy, n, rng, max_steps=steps),
            returns=play.returns,
            optimal_return=lambda r: gw.optimal_return(layout(), r, max_steps=steps),
            draw=lambda ax, ds: play.draw_trajectory(ax, layout(), ds),
        )
