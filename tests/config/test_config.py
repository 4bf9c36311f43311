"""Experiment configs: strict validation with one-line errors naming key, value and what is allowed."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from pcpg_dist.common.errors import ConfigError
from pcpg_dist.config import load_config, parse_config
from pcpg_dist.domains.gridworld.settings import PAPER_LAYOUTS

ROOT = Path(__file__).resolve().parents[2]
EXPERIMENTS = ROOT / "experiments"


def write(tmp_path: Path, data: dict) -> Path:
    (tmp_path / "gridworlds").mkdir(exist_ok=True)
    for env in ("E1", "E2"):
        (tmp_path / "gridworlds" / f"{env}.txt").write_text(
            (PAPER_LAYOUTS / f"{env}.txt").read_text()
        )
    path = tmp_path / "exp.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


BASE = {"name": "t", "gridworld": {"layout_dir": "gridworlds", "environments": ["E1", "E2"]}}


@pytest.mark.parametrize("name", sorted(p.name for p in EXPERIMENTS.glob("*.yaml")))
def test_shipped_configs_load(name):
    from pcpg_dist.config.overrides import load_config_with  # a sweep: section is split off

    cfg = load_config_with(EXPERIMENTS / name)
    assert cfg.name and cfg.flat()["name"] == cfg.name


def test_mlflow_params_hold_only_the_sections_that_act_on_the_run():
    """A GridWorld run's page listed ~40 params of Mario, MiniDungeons, logs and tuning."""
    grid = load_config(EXPERIMENTS / "quick.yaml").flat()
    mario = load_config(EXPERIMENTS / "mario.yaml").flat()
    assert {k.split(".")[0] for k in grid} >= {"gridworld", "pbtg", "clustering", "bc"}
    assert not any(
        k.startswith(("mario.", "minidungeons.", "trajectories.", "tuning.", "plugin"))
        for k in grid
    )
    assert "mario.path" in mario and not any(
        k.startswith(("gridworld.", "pbtg.", "tuning.")) for k in mario
    )


def test_layout_dir_is_relative_to_the_config_file(tmp_path):
    cfg = load_config(write(tmp_path, BASE))
    assert cfg.gridworld.layout_path("E1") == (tmp_path / "gridworlds" / "E1.txt").resolve()
    assert cfg.hash() == load_config(write(tmp_path, BASE)).hash()


def test_layout_dir_may_start_at_home_and_a_missing_file_names_both_keys(tmp_path, monkeypatch):
    """`~/layouts` was read as a folder named '~' beside the config; a missing layout named only
    gridworld.environments, though the folder is as likely wrong."""
    home = tmp_path / "home"
    shutil.copytree(PAPER_LAYOUTS, home / "layouts")
    monkeypatch.setenv("HOME", str(home))
    cfg = load_config(
        write(tmp_path, {**BASE, "gridworld": {"layout_dir": "~/layouts", "environments": ["E1"]}})
    )
    assert cfg.gridworld.layout_path("E1") == home / "layouts" / "E1.txt"
    with pytest.raises(
        ConfigError, match=r"not found \(keys gridworld.layout_dir, gridworld.environments\)"
    ):
        load_config(
            write(tmp_path, {**BASE, "gridworld": {"layout_dir": "~/none", "environments": ["E1"]}})
        )


def test_a_config_anywhere_runs_the_paper_layouts_without_naming_a_folder(tmp_path, monkeypatch):
    """The default layout_dir is the shipped E1-E5, whatever the config's or the shell's folder."""
    elsewhere = tmp_path / "a" / "b"
    elsewhere.mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    path = elsewhere / "mine.yaml"
    path.write_text(yaml.safe_dump({"name": "mine", "gridworld": {"environments": ["E1", "E5"]}}))
    cfg = load_config(path)
    assert cfg.gridworld.layout_path("E1") == PAPER_LAYOUTS / "E1.txt"
    assert cfg.gridworld.layout_text("E5") == (PAPER_LAYOUTS / "E5.txt").read_text()
    # the hash and the recorded config do not hold where pcpg is installed: same on every machine
    assert str(PAPER_LAYOUTS) not in cfg.model_dump_json() and cfg.gridworld.layout_dir is None
    path.write_text(yaml.safe_dump({"name": "m", "gridworld": {"environments": ["E9"]}}))
    with pytest.raises(ConfigError, match="E9"):
        load_config(path)


@pytest.mark.parametrize(
    "patch, needle",
    [
        (
            {"bogus": 1},
            "unknown top-level key 'bogus' — not a section or setting of a config (check the spelling)",
        ),
        (
            {"pbtg": {"episodes": -5}},
            "key 'pbtg.episodes': value -5 is not allowed — Input should be greater than or equal to 1",
        ),
        ({"pbtg": {"noise_max": "lots"}}, "key 'pbtg.noise_max': value 'lots'"),
        ({"seeds": [1, 1]}, "key 'seeds'"),
        ({"name": "../escape"}, "key 'name': value '../escape' is not allowed"),
        ({"name": "/abs"}, "key 'name'"),
        ({"gridworld": {"environments": ["E9"]}}, "E9.txt for environment 'E9' not found"),
        ({"domain": "chess"}, "key 'domain': value 'chess'"),
        ({"ranking": {"test_fraction": 0}}, "key 'ranking.test_fraction': value 0 is not allowed"),
        (
            {"clustering": {"k": 1}},
            "exp.yaml: clustering.k = 1 leaves no other cluster to corrupt labels into: "
            "set evaluation.corruption_levels to [0.0]",
        ),
        (
            {"ranking": {"style_margin": 1.0}, "clustering": {"method": "lstm_dec"}},
            "exp.yaml: ranking.style_margin needs a clusterer with a likelihood (clustering.method greedy_mix, "
            "bag_auto, policy_mix, choice_mix); lstm_dec gives none",
        ),
        ({"ranking": {"style_margin": -1}}, "key 'ranking.style_margin': value -1 is not allowed"),
        (
            {"clustering": {"restarts": 3, "confidence_runs": 0}},
            "section 'clustering': restarts 3 keeps the most stable restart, and stability needs "
            "refits: set confidence_runs >= 1, or restarts: 1",
        ),
        ({"clustering": {"restarts": 0}}, "key 'clustering.restarts': value 0 is not allowed"),
    ],
)
def test_bad_values_give_one_line(tmp_path, patch, needle):
    data = {**BASE, **patch}
    with pytest.raises(ConfigError) as e:
        load_config(write(tmp_path, data))
    msg = str(e.value)
    assert needle in msg and "\n" not in msg and "exp.yaml" in msg


@pytest.mark.parametrize(
    "patch, says",
    [
        (
            {"clustering": {"kk": 3}},
            "unknown key 'clustering.kk' — not a setting of section 'clustering'; "
            "did you mean 'clustering.k'?",
        ),
        (
            {"bcc": {"lr": 0.1}},
            "unknown top-level key 'bcc' — not a section or setting of a config; did you mean 'bc'?",
        ),
        (
            {"sed": 3},
            "unknown top-level key 'sed' — not a section or setting of a config; did you mean 'seed'?",
        ),
        (
            {"gridworld": {"environments": ["E1"], "envs": 1}},
            "unknown key 'gridworld.envs' — not a setting of section "
            "'gridworld'; did you mean 'gridworld.environments'?",
        ),
    ],
)
def test_a_misspelt_key_in_the_file_names_the_closest_like_an_override(tmp_path, patch, says):
    from pcpg_dist.config.overrides import load_config_with

    with pytest.raises(ConfigError) as e:
        load_config(write(tmp_path, {**BASE, **patch}))
    assert str(e.value) == f"{tmp_path / 'exp.yaml'}: {says}"
    if "clustering" in patch:  # the same typo on the command line names the same key
        with pytest.raises(ConfigError, match="did you mean 'clustering.k'"):
            load_config_with(write(tmp_path, BASE), ["clustering.kk=3"])


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
    assert (
        len(msg.splitlines()) == 1 and "key 'domain'" in msg and "did you mean 'gridworld'" in msg
    )
    for name in ("gridworld", "minidungeons", "mario", "trajectories"):
        assert name in msg


def test_trajectories_domain_needs_an_existing_path(tmp_path):
    with pytest.raises(ConfigError, match="needs trajectories.path"):
        load_config(write(tmp_path, {"name": "t", "domain": "trajectories"}))
    with pytest.raises(ConfigError, match="trajectories.path .*nope.parquet not found"):
        load_config(
            write(
                tmp_path,
                {"name": "t", "domain": "trajectories", "trajectories": {"path": "nope.parquet"}},
            )
        )
    (tmp_path / "logs.parquet").write_bytes(b"")
    cfg = load_config(
        write(
            tmp_path,
            {"name": "t", "domain": "trajectories", "trajectories": {"path": "logs.parquet"}},
        )
    )
    assert cfg.settings.path == str(
        (tmp_path / "logs.parquet").resolve()
    )  # relative to the config file


def test_a_domains_settings_are_checked_only_when_it_is_chosen(tmp_path):
    """A Mario config carries GridWorld's default layout folder, which need not exist."""
    cfg = load_config(
        write(tmp_path, {"name": "m", "domain": "mario", "gridworld": {"environments": ["nope"]}})
    )
    assert cfg.domain == "mario" and cfg.settings is cfg.mario


def test_loading_a_config_imports_no_torch_and_no_stage():
    import subprocess
    import sys

    code = (
        "import sys; from pcpg_dist.config.overrides import load_config_with; "
        f"[load_config_with(p) for p in {[str(p) for p in sorted(EXPERIMENTS.glob('*.yaml'))]!r}]; "
        "heavy = [m for m in ('torch', 'ray', 'mlflow', 'optuna', 'pcpg_dist.stages.bc', 'pcpg_dist.stages.clustering.step', "
        "'pcpg_dist.orchestration.tuning', 'pcpg_dist.orchestration.runner', 'pcpg_dist.stages.evaluation', 'pcpg_dist.stages.ranking') if m in sys.modules]; "
        "print(heavy)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


# ---------------------------------------------------------------- hostile and careless input (issue 18)
@pytest.mark.parametrize(
    "patch, needle",
    [
        (
            {"bc": {"betas": [2, -1]}},
            "key 'bc.betas': value [2, -1] is not allowed — Adam beta1 must lie in [0, 1)",
        ),
        ({"bc": {"betas": [0.9, 1.0]}}, "Adam beta2 must lie in [0, 1)"),
        (
            {"bc": {"lr": float("inf")}},
            "key 'bc.lr': value inf is not allowed — Input should be a finite number",
        ),
        ({"bc": {"lr": float("nan")}}, "key 'bc.lr'"),
        ({"bc": {"eps": float("inf")}}, "key 'bc.eps'"),
        (
            {"evaluation": {"corruption_levels": [-0.5]}},
            "corruption level c must lie in [0, 1], got -0.5",
        ),
        (
            {"evaluation": {"corruption_levels": [float("nan")]}},
            "key 'evaluation.corruption_levels.0': value nan",
        ),
        ({"evaluation": {"corruption_ps": [0.0]}}, "key 'evaluation.corruption_ps'"),
        ({"seed": 2**70}, "key 'seed'"),
        ({"ranking": {"split_seed": 2**70}}, "key 'ranking.split_seed'"),
        ({"evaluation": {"rollout_seed": -1}}, "key 'evaluation.rollout_seed'"),
        ({"tuning": {"seeds": [2**40]}}, "tuning.seeds must be integers in 0..4294967295"),
        ({"pbtg": {"initial_q": float("inf")}}, "key 'pbtg.initial_q'"),
        ({"runner": {"cpus_per_task": 10**9}}, "key 'runner.cpus_per_task'"),
        ({"bc": {"epochs": 10**12}}, "key 'bc.epochs'"),
        ({"trajectories": {"n_actions": 1e12}}, "key 'trajectories.n_actions'"),
        ({"tuning": {"k_range": [2, 10**6]}}, "k_range ends at most at 1000"),
        ({"tuning": {"enqueue": [{"k": 10**9}]}}, "enqueue: k=1000000000 outside 1..1000"),
        ({"tuning": {"ps": [2.0]}}, "tuning.ps: every p must lie in (0, 1]"),
        ({"name": "a" * 5000}, "has 5000 characters; at most 100"),
    ],
)
def test_numeric_fields_are_checked_against_their_real_domain(tmp_path, patch, needle):
    with pytest.raises(ConfigError) as e:
        load_config(write(tmp_path, {**BASE, **patch}))
    msg = str(e.value)
    assert needle in msg and "\n" not in msg and len(msg) < 700


@pytest.mark.parametrize(
    "patch, lower",
    [
        (
            {"pbtg": {"trajectories_per_style": 1e9}},
            "lower pbtg.trajectories_per_style or pbtg.max_steps",
        ),
        (
            {"evaluation": {"rollouts_per_policy": 10**7, "max_steps": 10**5}},
            "lower evaluation.rollouts_per_policy or evaluation.max_steps",
        ),
    ],
)
def test_memory_is_estimated_from_the_config_before_anything_is_allocated(tmp_path, patch, lower):
    import tracemalloc

    tracemalloc.start()
    with pytest.raises(ConfigError) as e:
        load_config(write(tmp_path, {**BASE, **patch}))
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    msg = str(e.value)
    assert lower in msg and "GiB of memory" in msg and "\n" not in msg
    assert peak < 20 << 20  # refused from the numbers alone, no array was built


def alias_bomb(levels: int = 9) -> str:
    lines = ["l0: &l0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]" for i in range(1, levels)]
    return "\n".join([*lines, f"name: *l{levels - 1}", ""])  # 9**9 = 387 million values


def test_yaml_alias_bomb_is_one_line_fast_and_small(tmp_path):
    import time
    import tracemalloc

    path = tmp_path / "bomb.yaml"
    path.write_text(alias_bomb())
    tracemalloc.start()
    t0 = time.perf_counter()
    with pytest.raises(ConfigError) as e:
        load_config(path)
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    msg = str(e.value)
    assert (
        "bomb.yaml, line" in msg and "expands to more than 100000 values" in msg and "\n" not in msg
    )
    assert peak < 20 << 20 and seconds < 10  # was 2 GB of error text and 14.5 GB of memory


@pytest.mark.parametrize(
    "text, where",
    [
        # a second section dropped every key of the first: bc.epochs 5 became the default 2000
        (
            "name: t\nbc:\n  epochs: 5\n  lr: 0.5\nclustering:\n  k: 3\nbc:\n  hidden_size: 7\n",
            "line 7: key 'bc' appears twice (first on line 2)",
        ),
        (
            "name: t\nclustering:\n  k: 3\n  k: 5\n",
            "line 4: key 'k' appears twice (first on line 3)",
        ),
        ("name: t\nclustering: {k: 3, k: 5}\n", "line 2: key 'k' appears twice (first on line 2)"),
        (
            "name: t\ngridworld:\n  gymnasium_kwargs: {a: 1, a: 2}\n",
            "line 3: key 'a' appears twice (first on line 3)",
        ),
    ],
)
def test_a_key_given_twice_in_the_file_is_refused_naming_both_lines(tmp_path, text, where):
    from pcpg_dist.config.overrides import load_config_with

    path = tmp_path / "exp.yaml"
    path.write_text(text)
    for load in (load_config, load_config_with):
        with pytest.raises(ConfigError) as e:
            load(path)
        assert str(e.value) == f"{path}, {where}; give each key once"


def test_a_key_that_extends_a_merged_mapping_is_no_repeat():
    text = "name: t\n_: &b {epochs: 5, lr: 0.5}\nbc:\n  <<: *b\n  lr: 0.1\n"
    from pcpg_dist.config.yaml_io import load_yaml_text

    assert load_yaml_text(text, "x.yaml")["bc"] == {"epochs": 5, "lr": 0.1}


@pytest.mark.parametrize(
    "item, key",
    [
        ("bc.epochs=true", "bc.epochs"),
        ("seed=true", "seed"),
        ("clustering.k=false", "clustering.k"),
        ("bc.lr=true", "bc.lr"),
        ("seeds=[0, true]", "seeds"),
    ],
)
def test_true_or_false_is_no_number(tmp_path, item, key):
    """Pydantic's lax mode read `bc.epochs=true` as 1 epoch."""
    from pcpg_dist.config.overrides import load_config_with

    path = write(tmp_path, BASE)
    with pytest.raises(ConfigError) as e:
        load_config_with(path, [item])
    assert str(e.value).startswith(f"{path}: key '{key}': value ") and str(e.value).endswith(
        "is not allowed — true/false is not a number; give a number"
    )
    cfg = load_config_with(
        path, ["bc.lr=1", "evaluation.corruption_levels=[0, 1]", "bc.betas=[0, 0.5]"]
    )
    assert (
        cfg.bc.lr == 1.0
        and cfg.evaluation.corruption_levels == (0.0, 1.0)
        and cfg.bc.betas == (0.0, 0.5)
    )


def test_an_override_given_twice_is_refused_not_the_last_taken(tmp_path):
    from pcpg_dist.config.overrides import load_config_with

    path = write(tmp_path, BASE)
    assert load_config_with(path, ["bc.epochs=5", "bc.lr=0.1"]).bc.epochs == 5
    with pytest.raises(ConfigError) as e:
        load_config_with(path, ["bc.epochs=5", "bc.epochs=7"])
    assert str(e.value) == (
        "override 'bc.epochs' is given twice on the command line ('bc.epochs=5' and "
        "'bc.epochs=7'); give it once as bc.epochs=VALUE"
    )


def test_an_optional_sections_keys_can_be_overridden_one_by_one(tmp_path):
    """`gridworld.random_layouts.count=2` was 'unknown config key'; the whole mapping was needed."""
    from pcpg_dist.config.overrides import load_config_with

    path = write(tmp_path, {"name": "r", "gridworld": {"random_layouts": {"count": 5, "seed": 11}}})
    cfg = load_config_with(path, ["gridworld.random_layouts.count=2"])
    assert cfg.gridworld.units == ["R0000", "R0001"] and cfg.gridworld.random_layouts.seed == 11
    fresh = write(tmp_path, {"name": "r"})
    assert (
        load_config_with(fresh, ["gridworld.random_layouts.count=3"]).gridworld.random_layouts.count
        == 3
    )
    assert load_config_with(path, ["gridworld.random_layouts={count: 1}"]).gridworld.units == [
        "R0000"
    ]
    with pytest.raises(ConfigError, match="did you mean 'gridworld.random_layouts.count'"):
        load_config_with(path, ["gridworld.random_layouts.cuont=2"])


@pytest.mark.parametrize(
    "content, needle",
    [
        (b"name: x\nseed: \xff\xfe\n", "bad.yaml, line 2: not UTF-8 text (byte 14)"),
        (b"a: &a [*a]\nname: x\n", "a YAML alias refers to a value that contains it"),
        (b"name: " + b"[" * 60 + b"]" * 60 + b"\n", "nested more than 50 levels deep"),
        (b"name: " + b"[" * 20_000 + b"]" * 20_000 + b"\n", "nested too deeply to read"),
        (b"name: x\n" + b"#" * (2 << 20), "a config file may hold at most 1048576 bytes"),
        (b"name: x\x00\n", "contains a NUL character"),
        (
            b"name: x\x04\n",
            "bad.yaml: not valid YAML (unacceptable character #x0004",
        ),  # found by tests/test_fuzz.py
        (b'name: x\n"a\\nb": 1\n', r"unknown top-level key 'a\nb'"),
    ],
)
def test_unreadable_config_files_are_one_line(tmp_path, content, needle):
    path = tmp_path / "bad.yaml"
    path.write_bytes(content)
    with pytest.raises(ConfigError) as e:
        load_config(path)
    assert needle in str(e.value) and "\n" not in str(e.value) and "bad.yaml" in str(e.value)


def test_a_config_that_is_not_a_regular_file_is_refused(tmp_path):
    with pytest.raises(ConfigError, match="/dev/zero: cannot read config .not a regular file"):
        load_config("/dev/zero")
    with pytest.raises(ConfigError, match="not a regular file"):
        load_config(tmp_path)


def test_huge_values_are_cut_in_error_messages():
    with pytest.raises(ConfigError) as e:
        parse_config({"name": ["x" * 10_000] * 10_000})
    assert len(str(e.value)) < 700 and "key 'name'" in str(e.value)


@pytest.mark.parametrize(
    "content, needle",
    [
        (b"..S.\n\xff.G.\n", "E1.txt, line 2: not UTF-8 text"),
        (b"." * (2 << 20), "at most 1048576 are allowed"),
        # within the byte limit, but ~30 min of layout analysis before generation started
        (
            b"S" + b"." * 998 + b"1\n" + (b"." * 1000 + b"\n") * 998 + b"2" + b"." * 998 + b"G\n",
            "E1.txt: 1000 columns x 1000 rows; a layout may be at most 100x100 cells",
        ),
    ],
)
def test_layout_files_are_checked_at_load(tmp_path, content, needle):
    path = write(tmp_path, BASE)
    (tmp_path / "gridworlds" / "E1.txt").write_bytes(content)
    with pytest.raises(ConfigError) as e:
        load_config(path)
    assert needle in str(e.value) and "layout file" in str(e.value) and "\n" not in str(e.value)


def test_mario_path_must_be_a_regular_file(tmp_path):
    with pytest.raises(ConfigError, match="mario.path play log /dev/zero is not a regular file"):
        load_config(write(tmp_path, {**BASE, "domain": "mario", "mario": {"path": "/dev/zero"}}))
