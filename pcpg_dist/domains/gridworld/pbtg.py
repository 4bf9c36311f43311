"""PBTG (Preference-Based Trajectory Generation) for GridWorld.

For each (environment, reward function): tabular Q-learning (20000 episodes, gamma 0.99, linear
epsilon decay) gives pi*_r; then each trajectory i is sampled from pi*_r perturbed with its own
noise level epsilon_i ~ U[noise_min, noise_max]: at every step a random valid move with probability
epsilon_i, else the greedy move. Skill therefore varies per trajectory and ranking by Performance
means something. The paper leaves the perturbation open; this is the project's documented choice.

The inner loops are numba-compiled over the domain's tables; one (E, R) pair is one pure function
call (:func:`generate_pair`), which the runner fans out as one Ray task. Seeds derive from
(base seed, environment, reward function) alone, so the data is bit-identical however it is run.
"""

from __future__ import annotations

import zlib

import numba
import numpy as np

from pcpg_dist.dataset import Dataset
from pcpg_dist.domains.gridworld.layout import FEATURES, N_ACTIONS, GridTables, Layout
from pcpg_dist.domains.gridworld.settings import PBTGConfig


def pair_seed(base_seed: int, env: str, reward_index: int) -> np.random.SeedSequence:
    """The seed of one (E, R) pair: a function of its key only, never of scheduling order."""
    return np.random.SeedSequence([int(base_seed), zlib.crc32(env.encode()), int(reward_index)])


@numba.njit(cache=True)
def _pick(valid_row: np.ndarray, q_row: np.ndarray, explore: bool) -> int:
    n_valid = 0
    for a in range(valid_row.shape[0]):
        n_valid += valid_row[a]
    if explore:
        k = np.random.randint(n_valid)
        for a in range(valid_row.shape[0]):
            if valid_row[a]:
                if k == 0:
                    return a
                k -= 1
    best, best_a = -np.inf, 0
    for a in range(valid_row.shape[0]):
        if valid_row[a] and q_row[a] > best:
            best, best_a = q_row[a], a
    return best_a


@numba.njit(cache=True)
def _q_learning(
    next_state,
    reward,
    terminal,
    valid,
    start,
    episodes,
    max_steps,
    gamma,
    lr,
    eps_start,
    eps_end,
    initial_q,
    seed,
):
    np.random.seed(seed)
    n_states, n_actions = next_state.shape
    q = np.full((n_states, n_actions), initial_q)
    for ep in range(episodes):
        eps = eps_start + (eps_end - eps_start) * ep / max(1, episodes - 1)
        s = start
        for _ in range(max_steps):
            a = _pick(valid[s], q[s], np.random.random() < eps)
            s2 = next_state[s, a]
            target = reward[s, a]
            if not terminal[s2]:
                best = -np.inf
                for b in range(n_actions):
                    if valid[s2, b] and q[s2, b] > best:
                        best = q[s2, b]
                if best > -np.inf:
                    target += gamma * best
            q[s, a] += lr * (target - q[s, a])
            s = s2
            if terminal[s]:
                break
    return q


@numba.njit(cache=True)
def _sample(next_state, terminal, valid, q, start, noise, max_steps, seed):
    np.random.seed(seed)
    n = noise.shape[0]
    states = np.empty(n * (max_steps + 1), np.int64)
    actions = np.empty(n * (max_steps + 1), np.int64)
    lengths = np.empty(n, np.int64)
    pos = 0
    for i in range(n):
        s, length = start, 1
        states[pos] = s
        for _ in range(max_steps):
            if terminal[s]:
                break
            a = _pick(valid[s], q[s], np.random.random() < noise[i])
            actions[pos] = a
            s = next_state[s, a]
            pos += 1
            states[pos] = s
            length += 1
        actions[pos] = -1
        pos += 1
        lengths[i] = length
    return states[:pos], actions[:pos], lengths


def q_learning(tables: GridTables, reward_index: int, cfg: PBTGConfig, seed: int) -> np.ndarray:
    """Tabular Q-learning for R_{reward_index + 1}; returns Q (S, A)."""
    return _q_learning(
        tables.next_state,
        tables.reward[reward_index],
        tables.terminal,
        tables.valid,
        tables.start,
        cfg.episodes,
        cfg.max_steps,
        cfg.gamma,
        cfg.learning_rate,
        cfg.epsilon_start,
        cfg.epsilon_end,
        cfg.initial_q,
        seed,
    )


def sample_trajectories(
    layout: Layout,
    q: np.ndarray,
    reward_index: int,
    n: int,
    cfg: PBTGConfig,
    rng: np.random.Generator,
) -> Dataset:
    """``n`` trajectories of the perturbed greedy policy of ``q``; style = reward_index."""
    t = layout.tables
    noise = rng.uniform(cfg.noise_min, cfg.noise_max, n)
    states, actions, lengths = _sample(
        t.next_state,
        t.terminal,
        t.valid,
        q,
        t.start,
        noise,
        cfg.max_steps,
        int(rng.integers(2**31)),
    )
    steps = actions >= 0
    rewards = np.zeros(len(states))
    rewards[steps] = t.reward[reward_index, states[steps], actions[steps]]
    offsets = np.r_[0, np.cumsum(lengths)].astype(np.int64)
    return Dataset(
        domain="gridworld",
        env=layout.name,
        n_actions=N_ACTIONS,
        states=t.features[states],
        actions=actions,
        valid=t.valid[states],
        rewards=rewards,
        offsets=offsets,
        trajectory_ids=np.arange(n, dtype=np.int64),
        styles=np.full(n, reward_index, np.int64),
        success=t.goal[states[offsets[1:] - 1]],
        epsilon=noise,
        feature_names=FEATURES,
    )


def generate_pair(layout: Layout, reward_index: int, cfg: PBTGConfig, base_seed: int) -> Dataset:
    """PBTG for one (E, R): Q-learning, ``trajectories_per_style`` perturbed trajectories, and of
    those the ``dataset_per_style`` that enter the environment's dataset D (a seeded sample).

    Sampling inside the pair keeps Ray transfers small and the result a function of the key only.
    """
    q_seed, sample_seed, pick_seed = pair_seed(base_seed, layout.name, reward_index).generate_state(
        3
    )
    q = q_learning(layout.tables, reward_index, cfg, int(q_seed))
    pool = sample_trajectories(
        layout,
        q,
        reward_index,
        cfg.trajectories_per_style,
        cfg,
        np.random.default_rng(int(sample_seed)),
    )
    pick = np.random.default_rng(int(pick_seed)).choice(
        pool.n_trajectories, cfg.dataset_per_style, replace=False
    )
    return pool.subset(np.sort(pick))


def assemble_dataset(pairs: list[Dataset]) -> Dataset:
    """Dataset D of one environment: its styles' samples, in style order, ids renumbered 0..n-1."""
    return Dataset.concat(sorted(pairs, key=lambda d: int(d.styles[0])))
