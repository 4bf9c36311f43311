"""MiniDungeons: rules, env API, level-file errors, proxy signatures, determinism, shipped levels."""

from __future__ import annotations

import json
from collections import deque
from pathlib import Path

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from pcpg_dist.common.errors import LayoutError
from pcpg_dist.domains.base import random_policy
from pcpg_dist.domains.minidungeons import (
    FEATURES,
    LEVELS_TEST,
    LEVELS_TRAIN,
    N_PROXIES,
    STATE_DIM,
    Game,
    MiniDungeonsEnv,
    generate_trajectories,
    level_names,
    load_level,
    outcome_stats,
    play,
    read_level,
    rollout,
)
from pcpg_dist.domains.minidungeons.game import MOVES
from pcpg_dist.domains.minidungeons.level import WALL
from pcpg_dist.domains.minidungeons.proxies import (
    BRAVE_HUNTER,
    MONSTER_KILLER,
    PURE_HUNTER,
    RECKLESS_RUNNER,
    SAFE_RUNNER,
    SAFETY_FIRST,
)

PROPS = {
    "PLAYER_MAX_HP": 30,
    "ENEMY_POWER": 10,
    "POTION_POWER": 10,
    "REWARDS": {"TURN": 1, "EXIT": 20, "KILL": 4, "TREASURE": 3, "POTION": 1, "DEAD": -20},
}

# A short way to the exit through a monster (row 1) and a safe detour (row 3); treasure (4,1) and
# potion (4,3) unguarded; treasure (5,7) guarded by the monster at (4,7); potion (5,9) guarded by (4,9).
SIGNATURE = """\
###########
#S...M...E#
#.#######.#
#.........#
#T#P###M#M#
#######T#P#
###########
"""


def make_level(tmp_path, stage: str, props: dict | str | None = None, name: str = "lvl"):
    (tmp_path / f"{name}.txt").write_text(stage)
    text = props if isinstance(props, str) else json.dumps(props or PROPS, indent=2)
    (tmp_path / f"{name}.json").write_text(text)
    return read_level(tmp_path / f"{name}.txt", tmp_path / f"{name}.json")


def walk(game: Game, actions: list[int], rng=None) -> list[float]:
    rng = rng or np.random.default_rng(0)
    return [game.step(a, rng)[0] for a in actions]


# ------------------------------------------------------------------- env API
@pytest.mark.parametrize("name", ["test", "holmgard_1"])
def test_check_env_passes(name):
    check_env(MiniDungeonsEnv(name), skip_render_check=True)


def test_env_seeded_reset_gives_identical_episodes():
    def episode(seed):
        env = MiniDungeonsEnv("holmgard_4")
        obs, _ = env.reset(seed=seed)
        out, rng = [obs], np.random.default_rng(1)
        done = False
        while not done:
            a = rng.choice(np.flatnonzero(env.action_masks()))
            obs, r, term, trunc, info = env.step(int(a))
            out.append(np.r_[obs, r, info["hp"]])
            done = term or trunc
        return np.concatenate(out)

    assert np.array_equal(episode(3), episode(3))


def test_walls_masked_in_every_reachable_position():
    for name in level_names():
        level = load_level(name)
        game = Game(level)
        h, w = level.shape
        seen, todo = {level.start}, deque([level.start])
        while todo:
            pos = todo.popleft()
            game.pos = pos
            mask = game.valid_mask()
            for a, (dr, dc) in enumerate(MOVES):
                r, c = pos[0] + dr, pos[1] + dc
                open_ = 0 <= r < h and 0 <= c < w and level.grid[r, c] != WALL
                assert mask[a] == open_, (name, pos, a)
                if open_ and (r, c) not in seen:
                    seen.add((r, c))
                    todo.append((r, c))
        assert level.exit in seen


def test_invalid_move_wastes_the_turn():
    game = Game(load_level("test"))
    assert not game.valid_mask()[3]  # start is on the left edge
    walk(game, [3])
    assert game.pos == load_level("test").start and game.t == 1


# ------------------------------------------------------------------- rules
def test_fight_costs_enemy_power_and_removes_the_monster(tmp_path):
    game = Game(make_level(tmp_path, "SM.E\n"))
    rewards = walk(game, [1])
    assert (game.hp, game.kills, game.damage, game.pos) == (20, 1, 10, (0, 1))
    assert game.remaining(4) == 0 and rewards == [-1 + 4]
    walk(game, [3, 1])  # walking back over the cell does not fight again
    assert game.hp == 20 and game.kills == 1


def test_random_damage_stays_in_range_and_varies(tmp_path):
    props = {**PROPS, "IS_ENEMY_POWER_RANDOM": True, "ENEMY_POWER_MIN": 5, "ENEMY_POWER_MAX": 14}
    level = make_level(tmp_path, "SM.E\n", props)
    damages = []
    for seed in range(200):
        game = Game(level)
        walk(game, [1], np.random.default_rng(seed))
        damages.append(game.damage)
    assert set(damages) == set(range(5, 15))


def test_potion_heal_is_capped_at_max_hp(tmp_path):
    game = Game(make_level(tmp_path, "SMP.E\n", {**PROPS, "POTION_POWER": 15}))
    walk(game, [1, 1])
    assert game.hp == 30 and game.potions == 1  # 20 + 15 capped at 30
    uncapped = Game(
        make_level(tmp_path, "SMP.E\n", {**PROPS, "POTION_POWER": 15, "IS_PLAYER_HP_LIMIT": False})
    )
    walk(uncapped, [1, 1])
    assert uncapped.hp == 35


def test_exit_is_success_and_death_is_failure(tmp_path):
    game = Game(make_level(tmp_path, "ST.E\n"))
    rewards = walk(game, [1, 1, 1])
    assert game.success and game.terminated and not game.dead and game.treasure == 1
    assert rewards[-1] == -1 + 20
    with pytest.raises(RuntimeError):
        walk(game, [3])
    weak = Game(make_level(tmp_path, "SMMM.E\n"))
    rewards = walk(weak, [1, 1, 1])
    assert weak.dead and weak.terminated and not weak.success and weak.hp == 0
    assert rewards[-1] == -1 + 4 - 20
    assert weak.features()[0] == 0.0


def test_turn_cap_truncates_as_failure(tmp_path):
    game = Game(make_level(tmp_path, "S..E\n"), max_steps=3)
    walk(game, [1, 3, 1])
    assert game.truncated and game.over and not game.terminated and not game.success


# ------------------------------------------------------------------- malformed files
@pytest.mark.parametrize(
    ("stage", "line", "words"),
    [
        ("S..\n...\n..\n..E\n", 3, "2 characters, expected 3"),
        ("S..\n.x.\n..E\n", 2, "unknown character 'x'"),
        ("...\n...\n..E\n", 1, "no start"),
        ("S..\n...\n...\n", 1, "no exit"),
        ("S..\n...\n.SE\n", 3, "second start"),
        ("S.#\n.#.\n#.E\n", 3, "cannot be reached"),
        ("", 1, "empty"),
    ],
)
def test_malformed_stage_names_file_and_line(tmp_path, stage, line, words):
    with pytest.raises(LayoutError) as e:
        make_level(tmp_path, stage)
    assert f"lvl.txt:{line}:" in str(e.value) and words in str(e.value)


@pytest.mark.parametrize(
    ("props", "line", "words"),
    [
        (
            '{\n  "PLAYER_MAX_HP": 30,\n  "ENEMY_POWER": 10,\n  "POTION_POWER" 10\n}',
            4,
            "invalid JSON",
        ),
        ({"ENEMY_POWER": 10, "POTION_POWER": 10}, 1, "missing key 'PLAYER_MAX_HP'"),
        ({**PROPS, "ENEMY_POWER": "ten"}, 3, "'ENEMY_POWER' must be a positive integer"),
        ({**PROPS, "IS_ENEMY_POWER_RANDOM": True}, 1, "missing key 'ENEMY_POWER_MIN'"),
        ({**PROPS, "REWARDS": {"TURN": 1}}, 5, "REWARDS.EXIT"),
        ("[1, 2]", 1, "expected a JSON object"),
    ],
)
def test_malformed_props_names_file_and_line(tmp_path, props, line, words):
    with pytest.raises(LayoutError) as e:
        make_level(tmp_path, "S.E\n", props)
    assert f"lvl.json:{line}:" in str(e.value) and words in str(e.value)


def test_unknown_level_name_is_a_layout_error():
    with pytest.raises(LayoutError, match="unknown level 'nope'"):
        load_level("nope")


# ------------------------------------------------------------------- proxies
@pytest.fixture(scope="module")
def signature_runs(tmp_path_factory):
    level = make_level(tmp_path_factory.mktemp("sig"), SIGNATURE)
    out = {}
    for proxy in range(N_PROXIES):
        _, game = play(level, proxy, 0.0, np.random.default_rng(0))
        out[proxy] = game
    return out


def test_every_proxy_reaches_the_exit_without_noise(signature_runs):
    assert all(g.success for g in signature_runs.values())


def test_safe_runner_takes_the_safe_detour_and_reckless_the_fight(signature_runs):
    safe, reckless = signature_runs[SAFE_RUNNER], signature_runs[RECKLESS_RUNNER]
    assert safe.kills == 0 and safe.hp == 30
    assert reckless.kills >= 1 and reckless.t < safe.t


def test_killer_kills_more_than_the_runners(signature_runs):
    k = signature_runs[MONSTER_KILLER].kills
    assert k == 3 and k > signature_runs[RECKLESS_RUNNER].kills > signature_runs[SAFE_RUNNER].kills


def test_pure_hunter_never_fights_and_brave_hunter_takes_guarded_treasure(signature_runs):
    pure, brave = signature_runs[PURE_HUNTER], signature_runs[BRAVE_HUNTER]
    assert pure.kills == 0 and pure.treasure == 1 and pure.potions == 0
    assert brave.treasure == 2 and brave.kills >= 1


def test_safety_first_collects_the_potions(signature_runs):
    sf = signature_runs[SAFETY_FIRST]
    assert sf.potions == 2 and sf.treasure == 1 and sf.hp == 30
    assert sf.potions > signature_runs[PURE_HUNTER].potions


def test_pure_hunter_never_fights_on_shipped_levels_without_noise():
    """Where a level forces no fight on the way out, the pure hunter and safe runner take none."""
    for name in ("test", "random_1", "gene_1", "gene_2", "strand_1", "holmgard_1", "holmgard_9"):
        for proxy in (SAFE_RUNNER, PURE_HUNTER):
            _, game = play(load_level(name), proxy, 0.0, np.random.default_rng(0))
            assert game.kills == 0 and game.success, (name, proxy)


def test_safe_runner_follows_the_exit_feature():
    """The features carry the plan: the noise-free safe runner's move is the exit direction."""
    ds = generate_trajectories("holmgard_2", SAFE_RUNNER, 2, seed=0, noise_range=(0.0, 0.0))
    i = FEATURES.index("exit_dy")
    rows = ds.step_rows
    dirs = ds.states[rows, i : i + 2]
    decoded = [MOVES.index((int(dy), int(dx))) for dy, dx in dirs]
    assert np.array_equal(decoded, ds.actions[rows])


# ------------------------------------------------------------------- data
def test_same_seed_same_dataset_and_other_seed_differs():
    a = generate_trajectories("hard", MONSTER_KILLER, 4, seed=7, noise_range=(0.1, 0.3))
    b = generate_trajectories("hard", MONSTER_KILLER, 4, seed=7, noise_range=(0.1, 0.3))
    c = generate_trajectories("hard", MONSTER_KILLER, 4, seed=8, noise_range=(0.1, 0.3))
    for f in ("states", "actions", "valid", "rewards", "offsets", "success", "epsilon"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert not np.array_equal(a.epsilon, c.epsilon)
    assert a.state_dim == STATE_DIM and a.feature_names == FEATURES
    assert (a.styles == MONSTER_KILLER).all() and ((a.epsilon >= 0.1) & (a.epsilon <= 0.3)).all()


def test_all_shipped_levels_load_and_every_proxy_finishes_within_the_cap():
    assert level_names() == [*LEVELS_TRAIN, *LEVELS_TEST] and len(level_names()) == 13
    for name in level_names():
        for proxy in range(N_PROXIES):
            ds = generate_trajectories(name, proxy, 3, seed=1, noise_range=(0.0, 0.2))
            stats = outcome_stats(ds)
            finished = stats.success | stats.died
            assert finished.mean() >= 2 / 3, (name, proxy)


def test_outcome_stats_match_the_game_counters():
    level = load_level("gene_2")
    rng = np.random.default_rng(3)
    games = []
    for _ in range(3):  # the same draws generate_trajectories makes: epsilon, then the episode
        eps = rng.uniform(0.1, 0.1)
        games.append(play(level, MONSTER_KILLER, eps, rng)[1])
    ds = generate_trajectories("gene_2", MONSTER_KILLER, 3, seed=3, noise_range=(0.1, 0.1))
    stats = outcome_stats(ds)
    assert list(stats.kills) == [g.kills for g in games]
    assert list(stats.treasure) == [g.treasure for g in games]
    assert list(stats.potions) == [g.potions for g in games]
    assert list(stats.steps) == [g.t for g in games] == list(ds.lengths - 1)
    assert list(stats.died) == [g.dead for g in games]


def test_rollout_respects_masks_and_rejects_invalid_actions():
    ds = rollout("holmgard_6", random_policy, 6, np.random.default_rng(0), max_steps=40)
    assert ds.n_trajectories == 6 and (ds.lengths <= 41).all()
    rows = ds.step_rows
    assert ds.valid_mask[rows, ds.actions[rows]].all()
    stats = outcome_stats(ds)
    assert ((stats.steps == 40) | stats.success | stats.died).all()

    def into_wall(states, valid, rng):
        return np.argmin(valid, axis=1) if (~valid).any() else np.zeros(len(valid), np.int64)

    with pytest.raises(ValueError, match="invalid"):
        rollout("test", into_wall, 2, np.random.default_rng(0))


def test_outcome_rollouts_play_the_agents_own_rollout_episodes(tmp_path, monkeypatch):
    """outcomes.csv and rollouts.csv describe the same agent: its extras' rollouts must use the
    evaluation's generator for that agent (seeded by its cell key). They used the cluster number,
    so one agent had two rollout figures (120.33 steps in one table, 120.1 in the other)."""
    from pcpg_dist.config import load_config
    from pcpg_dist.dataset import Dataset
    from pcpg_dist.domains.base import Unit
    from pcpg_dist.domains.minidungeons import domain as md_domain
    from pcpg_dist.domains.minidungeons.data import generate_trajectories
    from pcpg_dist.stages.evaluation import rollout_rng

    cfg = load_config(
        Path(__file__).resolve().parents[2] / "experiments" / "minidungeons_paper.yaml"
    )
    data = Dataset.concat(
        [generate_trajectories("holmgard_1", p, 2, seed=p) for p in range(6)], renumber=True
    )
    unit = Unit("levels", data, np.arange(data.n_trajectories))
    seen = {}

    def fake_rollout(cfg_, policy, n, rng):
        seen[policy] = rng.bit_generator.state
        return generate_trajectories("holmgard_1", 0, n, seed=0)

    class Trained:  # the agents of every cluster at the top p and first seed
        keys = [f"k{k}-p1-s{min(cfg.seeds)}" for k in range(cfg.clustering.k)]

        def policy(self, key, greedy):
            return key

    monkeypatch.setattr(md_domain, "held_out_rollout", fake_rollout)
    md_domain.MiniDungeonsDomain().extras(cfg, unit, data.styles, Trained(), tmp_path)
    assert sorted(seen) == sorted(Trained.keys)
    for key, state in seen.items():
        assert state == rollout_rng(cfg.evaluation.rollout_seed, key).bit_generator.state, key
    assert (tmp_path / "outcomes.csv").is_file()
