"""GridWorld as a registered domain: PBTG data, one unit per layout, rollouts and reward distances.

PBTG runs one Ray task per (layout, reward function); each layout is one unit with a seeded 80/20
trajectory split. The layouts simulate, so the evaluation gets rollouts, returns under every
style's reward, optimal returns and drawings (Tables 3/5, Figs. 5, 6, 8).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

from pcpg_dist.domains.base import Domain, DomainHooks, FanOut
from pcpg_dist.domains.defaults import in_process
from pcpg_dist.domains.gridworld.paper import PAPER
from pcpg_dist.domains.gridworld.settings import SECTIONS

N_STYLES = 4  # PBTG's reward functions: one style each


@lru_cache(maxsize=8)
def _random_family(count: int, seed: int):
    from pcpg_dist.domains.gridworld.layout import random_layouts

    return tuple(random_layouts(count, seed))


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
    if cfg.gridworld.random_layouts is not None:
        return {lt.name: lt for lt in gridworld_layouts(cfg)}[unit]
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
        if gw.random_layouts is not None:  # the layouts' text, so a generator change regenerates
            layouts = [lt.text() for lt in gridworld_layouts(cfg)]
        else:
            layouts = [gw.layout_text(e) for e in gw.environments]
        return [self.name, cfg.seed, cfg.pbtg, gw.units, layouts]

    def generate(self, cfg, show_progress: bool = True, fan_out: FanOut = in_process):
        from pcpg_dist.domains.gridworld.pbtg import assemble_dataset, generate_pair

        layouts = gridworld_layouts(cfg)
        calls = [(layout, r, cfg.pbtg, cfg.seed) for layout in layouts for r in range(N_STYLES)]
        pairs = fan_out(generate_pair, calls, "PBTG (E, R)", show_progress=show_progress)
        n = N_STYLES
        return {lt.name: assemble_dataset(pairs[n * i : n * i + n]) for i, lt in enumerate(layouts)}

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
        layout = gridworld_layout(cfg, unit)
        return DomainHooks(
            rollout=lambda policy, n, rng: play.rollout(layout, policy, n, rng, max_steps=steps),
            returns=play.returns,
            optimal_return=lambda r: gw.optimal_return(layout, r, max_steps=steps),
            draw=lambda ax, ds: play.draw_trajectory(ax, layout, ds),
        )
