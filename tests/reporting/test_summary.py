"""The terminal summary says which method clustered each environment, and why it fell back."""

from __future__ import annotations

from pathlib import Path

from rich.console import Console

from pcpg_dist.orchestration.points import RunResult
from pcpg_dist.reporting.summary import print_summary


def _printed(
    clustering: dict[str, dict[str, float]], method: str | None, metrics: dict | None = None
) -> str:
    result = RunResult(
        out_dir=Path("."),
        metrics=metrics or {"pcpg/accuracy/p1": 0.8, "baseline/accuracy/p1": 0.7},
        clustering=clustering,
    )
    console = Console(record=True, width=200)
    print_summary(result, console, method=method)
    return console.export_text()


def test_a_fall_back_is_named_in_the_table_and_explained_below_it():
    text = _printed(
        {
            "grid": {"clustering/accuracy": 0.9},
            "control": {"clustering/accuracy": 0.5, "clustering/auto_fell_back": 1.0},
        },
        "bag_auto",
    )
    assert "bag_auto -> policy_mix" in text
    rows = {line.split()[1]: line for line in text.splitlines() if line.strip().startswith("│")}
    assert "policy_mix" not in rows.get("grid", "") and "policy_mix" in rows["control"]
    assert "bag_auto clustered control with policy_mix: most of their states occur once" in text


def test_without_a_fall_back_nothing_is_explained():
    text = _printed({"grid": {"clustering/accuracy": 0.9}}, "greedy_mix")
    assert "greedy_mix" in text and "policy_mix" not in text


def test_a_choice_of_policy_mix_on_discrete_states_is_named_with_both_stabilities():
    chose = {
        "clustering/accuracy": 0.64,
        "clustering/stability": 0.95,
        "clustering/auto_chose_policy_mix": 1.0,
        "clustering/auto_stability_greedy_mix": 0.63,
        "clustering/auto_stability_policy_mix": 0.95,
    }
    kept = {**chose, "clustering/auto_chose_policy_mix": 0.0, "clustering/stability": 0.99}
    text = _printed({"views": chose, "grid": kept}, "bag_auto")
    rows = {line.split()[1]: line for line in text.splitlines() if line.strip().startswith("│")}
    assert "bag_auto -> policy_mix" in rows["views"] and "policy_mix" not in rows["grid"]
    assert "bag_auto clustered views with policy_mix" in text and "(0.63;" in text
    assert "clustered grid" not in text


def test_a_choice_of_the_time_step_is_named_with_both_stabilities():
    timed = {
        "clustering/accuracy": 0.97,
        "clustering/stability": 1.0,
        "clustering/auto_fell_back": 1.0,
        "clustering/auto_chose_policy_time": 1.0,
        "clustering/auto_stability_policy_mix": 0.77,
        "clustering/auto_stability_policy_mix_time": 1.0,
    }
    plain = {**timed, "clustering/auto_chose_policy_time": 0.0}
    text = _printed({"car": timed, "pole": plain}, "bag_auto")
    rows = {line.split()[1]: line for line in text.splitlines() if line.strip().startswith("│")}
    assert "bag_auto -> policy_mix (time)" in rows["car"]
    assert "(time)" not in rows["pole"] and "bag_auto -> policy_mix" in rows["pole"]
    assert "bag_auto clustered car with policy_mix seeing the time step" in text
    assert "(stability 1.00)" in text and "(0.77;" in text
    assert "clustered pole with policy_mix seeing" not in text


def test_the_cross_accuracy_and_reward_distances_are_said_in_words():
    result = RunResult(
        out_dir=Path("."),
        metrics={
            "pcpg/accuracy/p1": 0.8,
            "cross/diagonal_mean": 0.6084,
            "reward_distance/style0": 0.125,
            "reward_distance/style1": 1.5,
            "random/reward_distance/style0": 3.0,  # the random agent's: not listed
        },
        clustering={"grid": {"clustering/accuracy": 0.9}},
    )
    console = Console(record=True, width=300)
    print_summary(result, console, method=None)
    text = console.export_text()
    assert (
        "own cluster's held-out trajectories (the cross-accuracy diagonal, Table 4): 0.608" in text
    )
    assert "(Table 3, reward_distance/): style0 0.12, style1 1.50" in text
    assert "cross/diagonal_mean=" not in text and "3.00" not in text


def test_the_agents_start_is_said_where_the_verdict_doubts_the_styles():
    from pcpg_dist.config.stages import BCConfig

    def said(bc) -> str:
        result = RunResult(
            out_dir=Path("."),
            metrics={"pcpg/accuracy/p1": 0.8},
            clustering={
                "found": {"clustering/stability": 0.99},
                "doubted": {"clustering/stability": 0.40},
            },
        )
        console = Console(record=True, width=400)
        print_summary(result, console, method=None, bc=bc)
        return console.export_text()

    checked = said(BCConfig())
    assert "doubted: the verdict doubts the styles, so each per-cluster agent was fine-tuned" in (
        checked
    )
    assert "found:" not in checked and "bc.finetune_check" in checked
    assert "bc.finetune_check" not in said(BCConfig(finetune_check=0))
    assert "fine-tuned" not in said(BCConfig(init="scratch")) and "fine-tuned" not in said(None)


def test_pcpg_s_lead_over_no_clustering_is_printed_with_its_standard_error():
    metrics = {
        "pcpg/accuracy/p1": 0.81,
        "baseline/accuracy/p1": 0.76,
        "pcpg/lead_over_nc/p1": 0.05,
        "pcpg/lead_over_nc_se/p1": 0.0123,
        "pcpg/accuracy/p0.5": 0.8,  # a run without the lead (an older cache) prints a dash
    }
    text = _printed({"grid": {"clustering/accuracy": 0.9}}, None, metrics)
    rows = {line.split()[1]: line.split("│") for line in text.splitlines() if "│" in line}
    assert "PCPG - NC (± s.e.)" in text
    assert rows["1"][4].strip() == "+0.050 ± 0.012"
    assert rows["0.5"][4].strip() == "-"
