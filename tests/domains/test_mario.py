"""Mario play-log loading: the shipped data, every kind of malformed input, BC targets, profiles."""

from __future__ import annotations

import hashlib
import logging
from pathlib import Path

import numpy as np
import pandas as pd
import pydantic
import pytest

from pcpg_dist.common.errors import DataError
from pcpg_dist.dataset import Dataset
from pcpg_dist.domains.mario import log as mario

T = "#0,0,0#"


def write(tmp_path: Path, text: str, name: str = "play.log") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def line(*steps: str) -> str:
    return "|".join((*steps, T)) + "\n"


GOOD_A = line("0,0,0,0,0,0", "1,0,0,0,0,3", "1,1,0,0,0,13", "1,1,0,0,0,17")  # no death, won
GOOD_B = line("0,0,0,0,0,0", "0,0,1,0,0,25", "0,0,1,0,1,24", "0,0,1,1,1,6", "0,0,1,1,1,22")


@pytest.fixture(scope="module")
def shipped() -> mario.LoadResult:
    return mario.load_default(event="id")  # the log's six values as given


# ------------------------------------------------------------------ the shipped log
def test_shipped_file_is_the_published_log() -> None:
    path = mario.shipped_log_path()
    assert hashlib.sha256(path.read_bytes()).hexdigest() == mario.SHIPPED_SHA256
    assert "MIT License" in (path.parent / "LICENSE").read_text()


def test_shipped_log_loads_every_episode(shipped: mario.LoadResult) -> None:
    ds = shipped.dataset
    assert shipped.skipped == [] and shipped.skipped_steps == shipped.skipped_episodes == 0
    assert (ds.domain, ds.env, ds.n_actions) == ("mario", "smb", 39)
    assert ds.n_trajectories == mario.SHIPPED_EPISODES == 225
    assert ds.feature_names == mario.FEATURES and ds.state_dim == 6
    # data/README measures 57..1,458 fields per line, which counts the terminator as a step
    assert (ds.lengths.min(), ds.lengths.max(), ds.n_rows) == (56, 1457, 82354)
    assert set(np.unique(ds.states[:, 5]).astype(int)) == set(range(39))
    assert (ds.styles == -1).all() and np.isnan(ds.epsilon).all()
    assert ds.valid.shape == (ds.n_rows, 39) and ds.valid.all()


def test_shipped_counters_are_cumulative(shipped: mario.LoadResult) -> None:
    ds = shipped.dataset
    for i in range(ds.n_trajectories):
        counters = ds.trajectory_states(i)[:, :5]
        assert (np.diff(counters, axis=0) >= 0).all(), f"episode {i}"
        assert (counters >= 0).all()


def test_action_is_next_event(shipped: mario.LoadResult) -> None:
    ds = shipped.dataset
    for i in range(0, ds.n_trajectories, 17):
        a, b = ds.offsets[i], ds.offsets[i + 1]
        np.testing.assert_array_equal(
            ds.actions[a : b - 1], ds.states[a + 1 : b, 5].astype(np.int64)
        )
        assert ds.actions[b - 1] == -1


def test_shipped_goal_definitions() -> None:
    # 132 of 225 episodes contain a death (data/README); 138 end on the inferred won-level event
    assert mario.load_default(goal="no_death").dataset.success.sum() == 225 - 132
    assert mario.load_default(goal="any").dataset.success.all()
    assert mario.load_default(goal="won_level").dataset.success.sum() == 138


# ------------------------------------------------------------------ tidy input
def test_terminator_blank_lines_bom_and_crlf_are_accepted(tmp_path: Path) -> None:
    text = "\ufeff\n" + GOOD_A.replace("\n", "\r\n") + "\n   \n" + GOOD_B + "\n\n"
    result = mario.load_play_log(write(tmp_path, text))
    ds = result.dataset
    assert ds.n_trajectories == 2 and list(ds.lengths) == [4, 5]
    assert result.blank_lines == 5 and result.skipped == []
    assert list(ds.actions[:4]) == [3, 13, 17, -1]
    assert list(ds.actions[4:]) == [25, 24, 6, 22, -1]
    assert list(ds.success) == [True, False]
    bom_first = mario.load_play_log(
        write(tmp_path, "\ufeff" + GOOD_A, "bom.log"), event="id"
    ).dataset
    np.testing.assert_array_equal(bom_first.states[0], np.zeros(6))


def test_goal_options_on_hand_made_log(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD_A + GOOD_B)
    assert list(mario.load_play_log(path, goal="no_death").dataset.success) == [True, False]
    assert list(mario.load_play_log(path, goal="any").dataset.success) == [True, True]
    assert list(mario.load_play_log(path, goal="won_level").dataset.success) == [True, False]
    with pytest.raises(DataError, match="goal"):
        mario.load_play_log(path, goal="finish")  # type: ignore[arg-type]


def test_increments_option(tmp_path: Path) -> None:
    # starts mid-count (a kill on the first step, as 18 shipped episodes do)
    ds = mario.load_play_log(
        write(tmp_path, line("0,1,0,0,0,14", "1,1,0,0,0,3", "1,1,0,2,0,6")),
        increments=True,
        event="id",
    ).dataset
    assert ds.feature_names == (*mario.FEATURES, *mario.INCREMENTS)
    np.testing.assert_array_equal(
        ds.states[:, 6:], [[0, 1, 0, 0, 0], [1, 0, 0, 0, 0], [0, 0, 0, 2, 0]]
    )
    np.testing.assert_array_equal(
        ds.states[:, :6], [[0, 1, 0, 0, 0, 14], [1, 1, 0, 0, 0, 3], [1, 1, 0, 2, 0, 6]]
    )


def test_state_encodings(tmp_path: Path) -> None:
    path = write(tmp_path, line("0,1,0,0,0,14", "1,1,0,0,0,3", "1,1,0,2,0,38"))
    raw = mario.load_play_log(path, event="id").dataset
    onehot = mario.load_play_log(path).dataset  # the default: counters + one-hot event
    assert onehot.feature_names == (*mario.COUNTERS, *(f"event_{i}" for i in range(39)))
    np.testing.assert_array_equal(onehot.states[:, :5], raw.states[:, :5])
    np.testing.assert_array_equal(onehot.states[:, 5:].argmax(axis=1), [14, 3, 38])
    assert (onehot.states[:, 5:].sum(axis=1) == 1).all()
    lean = mario.load_play_log(path, counters=False, increments=True).dataset
    assert lean.feature_names == (*(f"event_{i}" for i in range(39)), *mario.INCREMENTS)
    np.testing.assert_array_equal(
        lean.states[:, 39:], [[0, 1, 0, 0, 0], [1, 0, 0, 0, 0], [0, 0, 0, 2, 0]]
    )
    np.testing.assert_array_equal(lean.actions, raw.actions)
    with pytest.raises(DataError, match="event must be"):
        mario.load_play_log(path, event="embedding")  # type: ignore[arg-type]


def test_single_step_episode_has_no_action(tmp_path: Path) -> None:
    ds = mario.load_play_log(write(tmp_path, line("0,0,0,0,0,0") + GOOD_A)).dataset
    assert list(ds.lengths) == [1, 4] and ds.actions[0] == -1 and len(ds.step_rows) == 3


# ------------------------------------------------------------------ messy input
BAD_STEPS = {
    "too few fields": ("1,0,0,0,3", "expected 6 comma-separated integers, got 5 fields"),
    "too many fields": ("1,0,0,0,0,3,9", "got 7 fields"),
    "empty step": ("", "got 1 fields"),
    "non-integer": ("1,0,x,0,0,3", "not an integer"),
    "float": ("1,0,0,0,0,3.0", "not an integer"),
    "negative counter": ("1,-1,0,0,0,3", "negative counter"),
    "event too large": ("1,0,0,0,0,39", "event id 39 outside 0..38"),
    "negative event": ("1,0,0,0,0,-1", "event id -1 outside 0..38"),
}


@pytest.mark.parametrize("case", sorted(BAD_STEPS))
def test_bad_step_strict_names_file_line_episode_step(tmp_path: Path, case: str) -> None:
    step, why = BAD_STEPS[case]
    path = write(tmp_path, GOOD_A + "\n" + line("0,0,0,0,0,0", step, "1,0,0,0,0,7"))
    with pytest.raises(DataError) as err:
        mario.load_play_log(path, strict=True)
    assert f"{path}:3: episode 1 step 1: " in str(err.value)
    assert why in str(err.value)


@pytest.mark.parametrize("case", sorted(BAD_STEPS))
def test_bad_step_lenient_drops_only_that_step(tmp_path: Path, case: str, caplog) -> None:
    step, why = BAD_STEPS[case]
    path = write(tmp_path, GOOD_A + line("0,0,0,0,0,0", step, "1,0,0,0,0,7"))
    with caplog.at_level(logging.WARNING, logger="pcpg_dist.domains.mario.log"):
        result = mario.load_play_log(path, strict=False)
    assert result.skipped_steps == 1 and result.skipped_episodes == 0
    assert (
        len(result.skipped) == 1
        and why in result.skipped[0]
        and ":2: episode 1 step 1" in result.skipped[0]
    )
    ds = result.dataset
    assert list(ds.lengths) == [4, 2]
    assert list(ds.actions[4:]) == [7, -1]  # the next readable event becomes the target
    assert result.counts["skipped_steps"] == 1 and "skipped_steps=1" in result.summary()
    assert any("skipped_steps=1" in r.getMessage() for r in caplog.records)


def test_missing_terminator(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD_A + "0,0,0,0,0,0|1,0,0,0,0,3\n")
    with pytest.raises(DataError, match=r":2: episode 1: no '#0,0,0#' terminator"):
        mario.load_play_log(path)
    result = mario.load_play_log(path, strict=False)
    assert result.unterminated_episodes == 1 and result.skipped_steps == 0
    assert list(result.dataset.lengths) == [4, 2]


def test_truncated_last_line(tmp_path: Path) -> None:
    """A file cut mid-write: no terminator and a half step."""
    path = write(tmp_path, GOOD_A + GOOD_B + "0,0,0,0,0,0|1,0,0,0,0,3|1,0,")
    with pytest.raises(DataError, match=":3: episode 2"):
        mario.load_play_log(path)
    result = mario.load_play_log(path, strict=False)
    assert (result.unterminated_episodes, result.skipped_steps, result.skipped_episodes) == (
        1,
        1,
        0,
    )
    assert list(result.dataset.lengths) == [4, 5, 2]


def test_decreasing_counter_drops_episode(tmp_path: Path) -> None:
    path = write(tmp_path, line("0,0,0,0,0,0", "2,0,0,0,0,3", "1,0,0,0,0,3") + GOOD_B)
    with pytest.raises(
        DataError, match="episode 0 step 2: cumulative counter 'jumps' decreases from 2 to 1"
    ):
        mario.load_play_log(path)
    result = mario.load_play_log(path, strict=False)
    assert result.skipped_episodes == 1 and result.dataset.n_trajectories == 1
    assert list(result.dataset.lengths) == [5]


def test_episode_without_readable_step_is_dropped(tmp_path: Path) -> None:
    path = write(tmp_path, line("a,b") + GOOD_A)
    result = mario.load_play_log(path, strict=False)
    assert (result.skipped_steps, result.skipped_episodes) == (1, 1)
    assert result.dataset.n_trajectories == 1 and result.dataset.trajectory_ids.tolist() == [0]


def test_nothing_readable_fails_even_when_lenient(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no readable episode"):
        mario.load_play_log(write(tmp_path, "\n\n"), strict=False)
    with pytest.raises(DataError, match="no readable episode"):
        mario.load_play_log(write(tmp_path, line("x") + line("1,2,3")), strict=False)
    with pytest.raises(DataError, match="cannot read play log"):
        mario.load_play_log(tmp_path / "missing.log")


def test_config_model(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD_A + GOOD_B)
    cfg = mario.MarioLoadConfig(path=path, goal="any", increments=True, event="id")
    ds = mario.load(cfg).dataset
    assert ds.success.all() and ds.state_dim == 11 and ds.n_trajectories == 2
    with pytest.raises(pydantic.ValidationError):
        mario.MarioLoadConfig(event="embedding")
    assert mario.load(mario.MarioLoadConfig()).dataset.n_trajectories == 225
    with pytest.raises(pydantic.ValidationError):
        mario.MarioLoadConfig(goal="finish")
    with pytest.raises(pydantic.ValidationError):
        mario.MarioLoadConfig(strictt=False)
    assert all(f.description for f in mario.MarioLoadConfig.model_fields.values())


# ------------------------------------------------------------------ valid events
def test_valid_mask_from_training_events(tmp_path: Path) -> None:
    ds = mario.load_play_log(write(tmp_path, GOOD_A + GOOD_B)).dataset
    train = ds.subset([0])
    mask = mario.valid_mask_from(train)
    assert np.flatnonzero(mask).tolist() == [3, 13, 17]
    restricted = mario.with_valid(ds, mask)
    assert restricted.valid_mask.shape == (ds.n_rows, 39)
    assert (restricted.valid_mask.sum(axis=1) == 3).all()
    assert restricted.valid_mask[:, [3, 13, 17]].all()
    np.testing.assert_array_equal(restricted.actions, ds.actions)
    with pytest.raises(DataError, match="non-empty"):
        mario.with_valid(ds, np.zeros(39, bool))
    with pytest.raises(DataError, match=r"\(39,\)"):
        mario.with_valid(ds, np.ones(40, bool))
    single = mario.load_play_log(write(tmp_path, line("0,0,0,0,0,0"), "one.log")).dataset
    with pytest.raises(DataError, match="no step with an action"):
        mario.valid_mask_from(single)


def test_valid_mask_of_the_highest_event(tmp_path: Path) -> None:
    ds = mario.load_play_log(write(tmp_path, line("0,0,0,0,0,0", "0,0,0,0,0,38"))).dataset
    assert np.flatnonzero(mario.valid_mask_from(ds)).tolist() == [38]
    assert mario.with_valid(ds, mario.valid_mask_from(ds)).valid_mask[:, 38].all()


# ------------------------------------------------------------------ held-out split
def _split(ds: Dataset, seed: int) -> tuple[Dataset, Dataset]:
    try:
        from pcpg_dist.domains.defaults import split_trajectories  # type: ignore[attr-defined]
    except ImportError:
        return mario.split_episodes(ds, 0.25, seed)
    train_idx, test_idx = split_trajectories(ds.n_trajectories, 0.25, seed)
    return ds.subset(train_idx), ds.subset(test_idx)


def test_split_keeps_episodes_whole(shipped: mario.LoadResult) -> None:
    ds = shipped.dataset
    train, test = _split(ds, 3)
    assert not set(train.trajectory_ids) & set(test.trajectory_ids)
    assert sorted([*train.trajectory_ids, *test.trajectory_ids]) == list(range(225))
    assert train.n_rows + test.n_rows == ds.n_rows
    for part in (train, test):  # every row of an episode went with it
        for i, tid in enumerate(part.trajectory_ids):
            np.testing.assert_array_equal(part.trajectory_states(i), ds.trajectory_states(int(tid)))
    again, _ = _split(ds, 3)
    other, _ = _split(ds, 4)
    assert list(again.trajectory_ids) == list(train.trajectory_ids)
    assert list(other.trajectory_ids) != list(train.trajectory_ids)


def test_split_episodes_rejects_empty_parts(shipped: mario.LoadResult) -> None:
    with pytest.raises(DataError):
        mario.split_episodes(shipped.dataset, 0.0, 0)
    with pytest.raises(DataError):
        mario.split_episodes(shipped.dataset.subset([0, 1]), 0.1, 0)


# ------------------------------------------------------------------ cluster profiles
def test_cluster_profile_values(tmp_path: Path) -> None:
    runner = line("0,0,0,0,0,0", "0,0,1,0,0,25", "1,0,1,0,0,3", "1,0,2,0,0,25")  # 4 steps
    killer = line("0,1,0,0,0,13", "0,2,0,0,0,13", "0,2,0,0,1,24", "0,2,0,0,1,22")  # 4 steps
    coiner = line(
        "0,0,0,0,0,0",
        "0,0,0,1,0,6",
        "0,0,0,2,0,6",
        "0,0,0,3,0,6",
        "0,0,0,3,0,6",
        "0,0,0,3,0,6",
        "0,0,0,3,0,6",
        "0,0,0,3,0,17",
    )  # 8 steps
    ds = mario.load_play_log(write(tmp_path, runner + killer + coiner + runner)).dataset
    profile = mario.cluster_profile(ds, np.array([5, 1, 1, 5]))
    lean = mario.load_play_log(
        write(tmp_path, runner + killer + coiner + runner, "lean.log"),
        counters=False,
        increments=True,
    ).dataset
    pd.testing.assert_frame_equal(mario.cluster_profile(lean, np.array([5, 1, 1, 5])), profile)
    assert list(profile.index) == [1, 5]
    assert list(profile["size"]) == [2, 2]
    assert list(profile["mean_length"]) == [6.0, 4.0]
    assert list(profile["success_rate"]) == [0.5, 1.0]
    assert profile.loc[5, "run_starts_per_step"] == pytest.approx(0.5)
    assert profile.loc[5, "jumps_per_step"] == pytest.approx(0.25)
    assert profile.loc[1, "kills_per_step"] == pytest.approx((2 / 4 + 0) / 2)
    assert profile.loc[1, "coins_per_step"] == pytest.approx((0 + 3 / 8) / 2)
    assert profile.loc[1, "deaths_per_step"] == pytest.approx(1 / 8)
    assert profile.loc[5, ["kills_per_step", "coins_per_step", "deaths_per_step"]].sum() == 0

    png = mario.plot_profile(profile, tmp_path / "fig" / "profile.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    import matplotlib.image

    assert matplotlib.image.imread(png).shape[:2] == (400, 1000)


def test_cluster_profile_rejects_bad_input(tmp_path: Path) -> None:
    ds = mario.load_play_log(write(tmp_path, GOOD_A + GOOD_B)).dataset
    with pytest.raises(DataError, match="labels must have shape"):
        mario.cluster_profile(ds, np.zeros(3))
    anonymous = Dataset.from_trajectories(
        "x",
        "y",
        2,
        [{"states": np.zeros((2, 6)), "actions": [0], "valid": [3, 3], "rewards": [0.0]}],
        styles=[-1],
        success=[True],
    )
    with pytest.raises(DataError, match="neither the Mario counters"):
        mario.cluster_profile(anonymous, np.zeros(1))
    with pytest.raises(DataError, match="profile lacks columns"):
        mario.plot_profile(
            mario.cluster_profile(ds, np.zeros(2)).drop(columns="size"), tmp_path / "p.png"
        )
