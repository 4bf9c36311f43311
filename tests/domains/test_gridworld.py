"""GridWorld: layouts, tables, value iteration, the Gymnasium env and rollouts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from pcpg_dist.common.errors import LayoutError
from pcpg_dist.domains.base import random_policy
from pcpg_dist.domains.gridworld import layout as gw
from pcpg_dist.domains.gridworld import play
from pcpg_dist.domains.gridworld.env import GridWorldEnv

LAYOUTS = Path(__file__).resolve().parents[2] / "pcpg_dist" / "data" / "gridworld"
ENVS = ["E1", "E2", "E3", "E4", "E5"]


@pytest.fixture(scope="module")
def layouts():
    return {e: gw.load_layout(LAYOUTS / f"{e}.txt") for e in ENVS}


def test_canonical_layouts_are_the_generators_output(layouts):
    for i, env in enumerate(ENVS, start=1):
        assert layouts[env].grid == gw.random_layout(i).grid
        assert layouts[env].width == 10 and layouts[env].height == 10


def test_styles_have_distinct_routes_and_signatures(layouts):
    for layout in layouts.values():
        assert gw.style_problem(layout) is None
        t = layout.tables
        routes = gw.optimal_routes(layout)
        assert len({tuple(r) for r in routes}) == 4
        for r, route in enumerate(routes):
            assert t.goal[route[-1]]
            assert tuple(t.features[route[-1], 2:].astype(int)) == gw.SIGNATURES[r]


def test_r1_takes_a_shortest_path_and_r2_visits_b1_before_g(layouts):
    for layout in layouts.values():
        t = layout.tables
        routes = gw.optimal_routes(layout)
        # BFS shortest distance S -> G over cells (walls, traps excluded).
        from collections import deque

        start, goal = layout.start, layout.find("G")[0]
        dist, q = {start: 0}, deque([start])
        while q:
            x, y = q.popleft()
            for dx, dy in gw.MOVES:
                n = (x + dx, y + dy)
                if (
                    0 <= n[0] < 10
                    and 0 <= n[1] < 10
                    and n not in dist
                    and layout.grid[n[1]][n[0]] not in "#X"
                ):
                    dist[n] = dist[(x, y)] + 1
                    q.append(n)
        assert len(routes[0]) - 1 == dist[goal]
        cells = [tuple(t.features[s, :2].astype(int)) for s in routes[1]]
        b1 = layout.find("1")[0]
        assert b1 in cells and cells.index(b1) < len(cells) - 1


def test_every_state_masks_walls_and_edges(layouts):
    for layout in layouts.values():
        t = layout.tables
        for s in np.nonzero(~t.terminal)[0]:
            x, y = (int(v) for v in t.features[s, :2])
            for a, (dx, dy) in enumerate(gw.MOVES):
                nx, ny = x + dx, y + dy
                inside = 0 <= nx < 10 and 0 <= ny < 10
                assert t.valid[s, a] == (inside and layout.grid[ny][nx] != "#")


def test_bonus_reward_only_on_first_visit(layouts):
    layout = layouts["E1"]
    t = layout.tables
    bx, by = layout.find("1")[0]
    for a, (dx, dy) in enumerate(gw.MOVES):
        px, py = bx - dx, by - dy
        if 0 <= px < 10 and 0 <= py < 10 and layout.grid[py][px] in ".S2":
            fresh = ((py * 10 + px) * 2 + 0) * 2 + 0
            seen = ((py * 10 + px) * 2 + 1) * 2 + 0
            assert t.reward[1, fresh, a] == 50 and t.reward[1, seen, a] == 0
            assert t.reward[0, fresh, a] == 0
            assert t.features[t.next_state[fresh, a], 2] == 1
            return
    pytest.fail("no floor cell next to B1")


def test_check_env_and_episode_end(layouts):
    env = GridWorldEnv(layouts["E1"], reward_index=3)
    check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=0)
    assert tuple(obs[:2]) == layouts["E1"].start and info["action_mask"].any()
    route = gw.optimal_routes(layouts["E1"])[3]
    t = layouts["E1"].tables
    total = 0.0
    for s, s2 in zip(route, route[1:], strict=False):
        a = int(np.nonzero(t.next_state[s] == s2)[0][0])
        obs, r, term, trunc, info = env.step(a)
        total += r
    assert term and not trunc and info["success"] and total == 200.0


def test_invalid_action_is_a_no_op_and_cap_truncates(layouts):
    env = GridWorldEnv(layouts["E1"], max_steps=3)
    obs, _ = env.reset(seed=0)
    bad = np.nonzero(~env.action_masks())[0]
    if len(bad):
        obs2, r, *_, info = env.step(int(bad[0]))
        assert (obs2 == obs).all() and r == 0 and info["invalid_action"]
    env.reset(seed=0)
    good = int(np.nonzero(env.action_masks())[0][0])
    out = [
        env.step(good if env.action_masks()[good] else int(np.nonzero(env.action_masks())[0][0]))
        for _ in range(3)
    ]
    assert out[-1][2] or out[-1][3]


@pytest.mark.parametrize(
    "text, needle",
    [
        ("S.G\n.12\n..", "line 3: 2 characters, expected 3"),
        ("S.G\n.1Z\n...", "unknown character 'Z'"),
        ("S.G\n.1.\n...", "exactly one '2'"),
        ("S.G\n.12\nSS.", "exactly one 'S'"),
        ("S#G\n#12\n...", "goal G is not reachable"),
        ("SXG\nX12\n...", "goal G is not reachable"),
        ("S.G\n.X.\n1X2", "bonus 2 is not reachable"),
        ("", "empty layout"),
    ],
)
def test_bad_layouts_name_the_problem(text, needle, tmp_path):
    path = tmp_path / "mine.txt"
    path.write_text(text)
    with pytest.raises(LayoutError, match="mine.txt") as e:
        gw.load_layout(path)
    assert needle in str(e.value)


def test_layout_size_is_bounded_before_it_is_analysed():
    """Analysis grows as side^3 (1.5 s at 100x100, 13 s at 200x200): a wider layout is refused at once."""

    def layout(width: int) -> str:
        return "S" + "." * (width - 2) + "G\n1" + "." * (width - 2) + "2\n" + "." * width

    assert gw.parse_layout(layout(100), "wide.txt", check_styles=False).width == 100
    with pytest.raises(LayoutError) as e:
        gw.parse_layout(layout(101), "wide.txt")
    assert str(e.value).startswith(
        "wide.txt: 101 columns x 3 rows; a layout may be at most 100x100 cells"
    )
    with pytest.raises(LayoutError, match="wide.txt: 2 columns x 101 rows"):
        gw.parse_layout("S1\n" + "..\n" * 99 + "G2\n", "wide.txt")


def test_user_layout_with_coinciding_styles_warns(tmp_path):
    path = tmp_path / "line.txt"
    path.write_text("S12G\n....\n")  # every route passes both bonuses
    with pytest.warns(UserWarning, match="R1's optimal route ends with"):
        layout = gw.load_layout(path)
    assert layout.name == "line"


def test_missing_layout_file(tmp_path):
    with pytest.raises(LayoutError, match="nope.txt"):
        gw.load_layout(tmp_path / "nope.txt")


def test_rollout_of_random_policy_and_returns(layouts, rng):
    layout = layouts["E2"]
    ds = play.rollout(layout, random_policy, 200, rng, max_steps=100, reward_index=3)
    assert ds.n_trajectories == 200 and ds.lengths.max() <= 101
    t = layout.tables
    idx = t.state_index(ds.states, layout.width)
    steps = ds.step_rows
    assert t.valid[idx[steps], ds.actions[steps]].all()
    per_traj = np.add.reduceat(ds.rewards, ds.offsets[:-1])
    np.testing.assert_allclose(per_traj, play.returns(ds, 3))
    assert gw.optimal_return(layout, 3) == 200.0


def test_k_above_the_trajectories_the_config_will_make_is_refused_at_load():
    """`clustering.k` above 4 styles x pbtg.dataset_per_style: one line when the config loads
    (it was refused only after the data was generated, 40 s in)."""
    from pcpg_dist.common.errors import PcpgError
    from pcpg_dist.config import parse_config

    raw = {"name": "x", "pbtg": {"dataset_per_style": 30}, "clustering": {"k": 121}}
    with pytest.raises(
        PcpgError, match=r"clustering.k.*121 clusters, but each layout will have 120"
    ):
        parse_config(raw, source="x")
    assert parse_config({**raw, "clustering": {"k": 120}}, source="x").clustering.k == 120
