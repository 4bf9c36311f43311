"""The smallest whole GridWorld run, as a YAML text (one layout, one seed, p = 1, a few epochs):
what the end-to-end tests of an install or a full disk run from an empty folder."""

from __future__ import annotations


def mini_yaml(episodes: int = 20000, epochs: int = 50, figures: bool = True) -> str:
    return f"""\
name: mini
seeds: [0]
gridworld:
  environments: [E1]
pbtg:
  episodes: {episodes}
  trajectories_per_style: 60
  dataset_per_style: 30
clustering:
  k: 4
  pretrain_epochs: 2
  dec_epochs: 1
  ceiling: false
  confidence_runs: 0
ranking:
  ps: [1.0]
bc:
  epochs: {epochs}
  hidden_size: 8
evaluation:
  rollouts_per_policy: 4
  corruption_levels: [0.0]
{"" if figures else "  figures: false" + chr(10)}"""
