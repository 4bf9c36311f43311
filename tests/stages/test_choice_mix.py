"""choice_mix: clustering by what each legal move does (``clustering.move_features``)."""

from __future__ import annotations

import numpy as np
import pytest
from move_toy import players

from pcpg_dist.common.devices import set_threads
from pcpg_dist.common.errors import DataError
from pcpg_dist.config import parse_config
from pcpg_dist.stages.clustering import ClusterConfig, cluster, clustering_metrics, load_model
from pcpg_dist.stages.clustering.choice_mix import fit_choice_mix
from pcpg_dist.stages.clustering.move_pairs import load_move_features, pairs_of

MOVES = "move_toy:features"


@pytest.fixture(scope="module")
def log():
    set_threads(1)
    return players(30, seed=3)


@pytest.fixture(scope="module")
def fitted(log):
    return cluster(log, ClusterConfig(k=3, move_features=MOVES, confidence_runs=0), seed=0)


def test_the_default_uses_the_move_features_and_finds_the_styles(log, fitted):
    assert fitted.metrics["auto_chose_choice_mix"] == 1.0
    assert fitted.model.method == "choice_mix"
    assert clustering_metrics(log.styles, fitted.labels)["accuracy"] >= 0.95
    assert fitted.margins is not None and (fitted.margins >= 0).all()
    # the ids alone say nothing: a mixture of policies over ids and states is far below
    ids_only = cluster(log, ClusterConfig(k=3, method="visits_kmeans"), seed=0)
    assert clustering_metrics(log.styles, ids_only.labels)["accuracy"] < 0.7


def test_same_seed_same_labels(log, fitted):
    again = cluster(log, ClusterConfig(k=3, move_features=MOVES, confidence_runs=0), seed=0)
    np.testing.assert_array_equal(again.labels, fitted.labels)
    np.testing.assert_array_equal(again.margins, fitted.margins)


def test_what_each_cluster_weighs_reads_the_styles(log, fitted):
    from move_toy import PREFERENCES

    from pcpg_dist.stages.clustering.style_weights import setting_apart, style_weights_of

    table = style_weights_of(fitted.model)
    assert list(table["feature"]) == ["first", "second", "third", "fourth"]
    apart = setting_apart(table, top=1)
    for style, prefs in enumerate(PREFERENCES):
        col = f"k{np.bincount(fitted.labels[log.styles == style]).argmax()}"
        liked = int(prefs.argmax())
        # the style's cluster weighs the feature the style prefers more than any other cluster,
        # and that is what sets it apart
        assert table.loc[liked, ["k0", "k1", "k2"]].astype(float).idxmax() == col
        assert apart[col][0][0] == table.at[liked, "feature"] and apart[col][0][1] > 0
    assert style_weights_of(None) is None


def test_a_log_that_offers_ids_that_are_no_moves_is_told_by_the_function():
    """A log without action masks offers ids that are no moves there; a function that returns
    (features, playable) leaves them out of every step, and the styles are found as before."""
    offering = players(30, seed=4, offered=6)
    spec = "move_toy:with_playable"
    pairs = pairs_of(offering, load_move_features(spec), spec)
    steps = len(pairs.chosen)
    decisions = offering.valid[np.asarray(offering.actions) >= 0]
    assert len(pairs.phi) == int(decisions.sum()) - 6 * steps  # the offered ids left out
    found = cluster(offering, ClusterConfig(k=3, move_features=spec, confidence_runs=0), seed=0)
    assert clustering_metrics(offering.styles, found.labels)["accuracy"] >= 0.95


def test_starts_run_side_by_side_give_the_same_fit(log):
    pairs = pairs_of(log, load_move_features(MOVES), MOVES)
    one, two = (fit_choice_mix(pairs, 3, seed=1, threads=n) for n in (1, 2))
    np.testing.assert_array_equal(one.labels, two.labels)
    np.testing.assert_array_equal(one.w, two.w)
    assert one.loglik == two.loglik


def test_saved_model_predicts_the_same_and_unseen_trajectories(tmp_path, log, fitted):
    fitted.model.save(tmp_path / "m")
    model = load_model(tmp_path / "m", move_features=MOVES)
    np.testing.assert_array_equal(model.predict(log), fitted.labels)
    fresh = players(10, seed=99)
    assert clustering_metrics(fresh.styles, model.predict(fresh))["accuracy"] >= 0.9
    # pcpg classify from Python, given the same function
    from pcpg_dist.api.calls import classify

    table = classify(tmp_path / "m", fresh, move_features=MOVES)
    np.testing.assert_array_equal(table.predicted_style.to_numpy(), model.predict(fresh))
    # and says what each cluster weighs, as the run did
    weights = table.attrs["style_weights"]
    assert weights["feature"] == ["first", "second", "third", "fourth"]
    np.testing.assert_allclose(weights["k0"], fitted.model.choice[0][0])


@pytest.mark.parametrize(
    "given, says",
    [
        (None, "pcpg runs no code a model file names: give it yourself"),
        ("move_toy:with_nan", "fitted with move features 'move_toy:features'; given"),
    ],
)
def test_a_model_file_never_chooses_the_code_pcpg_runs(tmp_path, fitted, given, says):
    fitted.model.save(tmp_path / "m")
    with pytest.raises(DataError, match="cluster_model.json") as got:
        load_model(tmp_path / "m", move_features=given)
    assert says in str(got.value) and "\n" not in str(got.value)


def test_a_confidence_is_measured(log):
    got = cluster(log, ClusterConfig(k=3, move_features=MOVES, confidence_runs=2), seed=0)
    assert got.model.method == "choice_mix"
    assert clustering_metrics(log.styles, got.labels)["accuracy"] >= 0.95


@pytest.mark.parametrize(
    "spec, says",
    [
        ("move_toy:nothing_here", "cannot import 'move_toy:nothing_here'"),
        ("no_such_module_xyz:f", "cannot import 'no_such_module_xyz:f'"),
        ("move_toy:NOT_A_FUNCTION", "is a int, not a function"),
        ("move_toy:wrong_width", "returned shape (12, 3)"),
        ("move_toy:with_nan", "NaN or infinite values"),
        ("move_toy:wrong_names", "move_toy:wrong_names.names must be a list of 4 names"),
        ("move_toy:none_playable", "says the log's move"),
        (
            "move_toy:playable_of_wrong_shape",
            "shape (7,); it must be 6 booleans, one per offered move",
        ),
    ],
)
def test_a_bad_move_feature_function_is_one_line(log, spec, says):
    with pytest.raises(DataError, match="clustering.move_features") as got:
        cluster(log, ClusterConfig(k=3, move_features=spec, confidence_runs=0), seed=0)
    assert says in str(got.value) and "\n" not in str(got.value)


def test_the_setting_must_name_a_function():
    with pytest.raises(Exception, match="move_features"):
        parse_config({"name": "x", "clustering": {"move_features": "../evil.py"}})


def test_the_ceiling_has_the_choice_models_given_the_styles(log):
    from pcpg_dist.stages.clustering.ceiling import ceiling_panel

    panel = ceiling_panel(log, seed=0, move_features=MOVES)
    assert panel["choice_likelihood"] >= 0.95
    # the panel's other views read ids, which say nothing here
    assert max(v for n, v in panel.items() if n != "choice_likelihood") < 0.8, panel
    assert "choice_likelihood" not in ceiling_panel(log, seed=0)


def test_pcpg_classify_says_what_sets_each_cluster_apart(tmp_path, fitted, capsys):
    from pcpg_dist.cli import main
    from pcpg_dist.dataset import write_parquet

    fitted.model.save(tmp_path / "m")
    write_parquet(players(5, seed=98), tmp_path / "fresh.parquet")
    args = ["classify", str(tmp_path / "m"), str(tmp_path / "fresh.parquet"), "--move-features"]
    out = tmp_path / "labels.csv"
    assert main([*args, MOVES, "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "m: what sets each cluster apart" in said and "first +" in said and out.is_file()
