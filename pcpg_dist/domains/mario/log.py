"""Mario: human Super Mario Bros play logs (the PCPG paper's natural, unlabelled domain).

The shipped log (``pcpg_dist/data/mario/``, MIT, see docs/mario.md for provenance) is the S-TLI
play log of Arendse, Ingram & Rosman (2022): one episode per line, steps separated by ``|``, each
step six integers ``JumpStart, Kill, RunStateStart, BlockCoinDestroy, Die, CorpusIndex`` and the
line closed by a ``#0,0,0#`` terminator. The first five are counters, cumulative since the start
of the episode; ``CorpusIndex`` (0..38) is the id of the event at that step. This is exactly the
paper's state tuple (j, k, r, c, d, e).

How the paper's pipeline reads it (documented in docs/mario.md):

- **State**: the five counters, the current event (one-hot by default; ``event="id"`` keeps the
  raw number), optionally the five per-step increments; ``counters=False`` drops the counters.
- **Action** (the behavioural-cloning target): the *next* step's event id; the final row has -1.
  ``n_actions`` = 39. By default every event is valid; :func:`valid_mask_from` and
  :func:`with_valid` restrict the valid set to the events seen in a training split.
- **Goal** (for Performance, Eq. 3): by default an episode succeeds when it ends with no death.

There is no simulator: this domain loads data only, so it has no rollout.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd

from pcpg_dist.common.errors import DataError
from pcpg_dist.dataset import Dataset
from pcpg_dist.domains.mario.log_lines import (
    COUNTERS,
    N_ACTIONS,
    Tally,
    episode_arrays,
    episode_success,
    parse_episode,
)
from pcpg_dist.domains.mario.settings import (
    MAX_PLAY_LOG_BYTES,
    EventEncoding,
    Goal,
    MarioLoadConfig,
)

log = logging.getLogger(__name__)

DOMAIN = "mario"
ENV = "smb"  # the log carries no level ids, so every episode belongs to one environment
FEATURES = (*COUNTERS, "event")
INCREMENTS = tuple(f"d_{c}" for c in COUNTERS)
SHIPPED_PACKAGE = "pcpg_dist"
SHIPPED_PATH = ("data", "mario", "mario_stli_all_levels.log")
SHIPPED_SHA256 = "ff427eb617213f81c138d67c707a6ec953fa79154d3566c940ffbe1ae08e876b"
SHIPPED_EPISODES = 225

EVENT_ONEHOT = tuple(f"event_{i}" for i in range(N_ACTIONS))


@dataclass(frozen=True)
class LoadResult:
    """A loaded play log and what was left out of it (always empty when ``strict``)."""

    dataset: Dataset
    skipped: list[str] = field(default_factory=list)  # one message per problem, with file:line
    skipped_steps: int = 0
    skipped_episodes: int = 0
    unterminated_episodes: int = 0  # kept, but their line had no '#...#' terminator
    blank_lines: int = 0

    @property
    def counts(self) -> dict[str, int]:
        return {
            "episodes": self.dataset.n_trajectories,
            "steps": self.dataset.n_rows,
            "skipped_steps": self.skipped_steps,
            "skipped_episodes": self.skipped_episodes,
            "unterminated_episodes": self.unterminated_episodes,
            "blank_lines": self.blank_lines,
        }

    def summary(self) -> str:
        """One line for a log or a tracking tag."""
        return ", ".join(f"{k}={v}" for k, v in self.counts.items())


def feature_names(
    event: EventEncoding = "onehot", counters: bool = True, increments: bool = False
) -> tuple[str, ...]:
    """State feature names, in order: counters, the event, increments (each where chosen)."""
    return (
        ((*COUNTERS,) if counters else ())
        + (EVENT_ONEHOT if event == "onehot" else ("event",))
        + (INCREMENTS if increments else ())
    )


def load_play_log(
    path: str | Path,
    strict: bool = True,
    goal: Goal = "no_death",
    increments: bool = False,
    event: EventEncoding = "onehot",
    counters: bool = True,
) -> LoadResult:
    """Read an S-TLI play log into a Dataset (domain 'mario', env 'smb', styles unknown).

    Every problem names the file, the line, the episode (0-based, counting non-blank lines)
    and the step. ``strict`` raises :class:`DataError` on the first one; otherwise a malformed
    step (wrong field count, non-integer, negative counter, event id outside 0..38) is dropped,
    an episode whose counters decrease (corrupt: they are cumulative) or that has no readable
    step is dropped, and an episode without its terminator is kept — each counted in the result
    and logged as a warning. Blank lines are ignored in both modes.
    """
    path = Path(path)
    if goal not in ("no_death", "any", "won_level"):
        raise DataError(f"goal must be 'no_death', 'any' or 'won_level', got {goal!r}")
    if event not in ("onehot", "id"):
        raise DataError(f"event must be 'onehot' or 'id', got {event!r}")
    text = _read_log_text(path)
    tally = Tally(strict)
    trajectories: list[dict[str, np.ndarray]] = []
    success: list[bool] = []
    episode = -1
    for line_no, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            tally.blank += 1
            continue
        episode += 1
        arr = parse_episode(line, f"{path}:{line_no}: episode {episode}", tally)
        if arr is not None:
            trajectories.append(episode_arrays(arr, event, counters, increments))
            success.append(episode_success(arr, goal))
    problems = tally.problems
    if not trajectories:
        raise DataError(
            f"{path}: no readable episode ({len(problems)} problems; first: "
            f"{problems[0] if problems else 'the file is empty'})"
        )
    names = feature_names(event, counters, increments)
    dataset = Dataset.from_trajectories(
        DOMAIN,
        ENV,
        N_ACTIONS,
        trajectories,
        styles=[-1] * len(trajectories),
        success=success,
        feature_names=names,
    )
    result = LoadResult(
        dataset,
        problems,
        tally.skipped_steps,
        tally.skipped_episodes,
        tally.unterminated,
        tally.blank,
    )
    if problems:
        shown = "; ".join(problems[:5]) + (" ..." if len(problems) > 5 else "")
        log.warning("%s: loaded with problems (%s): %s", path, result.summary(), shown)
    return result


def _read_log_text(path: Path) -> str:
    """The log's text, from a regular file of at most MAX_PLAY_LOG_BYTES (a BOM is not data)."""
    try:
        if not path.is_file():  # a FIFO or /dev/zero would block or never end
            raise DataError(
                f"{path}: cannot read play log ("
                + ("not a regular file)" if path.exists() else "not found)")
            )
        if path.stat().st_size > MAX_PLAY_LOG_BYTES:
            raise DataError(
                f"{path}: {path.stat().st_size} bytes; a play log may hold at most {MAX_PLAY_LOG_BYTES} "
                f"(split it)"
            )
        return path.read_text(encoding="utf-8-sig", errors="replace")
    except OSError as e:
        raise DataError(f"{path}: cannot read play log ({e.strerror or e})") from None


def load(cfg: MarioLoadConfig) -> LoadResult:
    """Load ``cfg.path`` (the shipped log when None) with the options of ``cfg``."""
    options = cfg.model_dump(exclude={"path"})
    return load_default(**options) if cfg.path is None else load_play_log(cfg.path, **options)


def load_default(
    strict: bool = True,
    goal: Goal = "no_death",
    increments: bool = False,
    event: EventEncoding = "onehot",
    counters: bool = True,
) -> LoadResult:
    """The shipped log (225 human episodes), read from package data — never from /work/shared."""
    resource = resources.files(SHIPPED_PACKAGE).joinpath(*SHIPPED_PATH)
    with resources.as_file(resource) as path:
        if not Path(path).is_file():
            raise DataError(
                f"{path}: the shipped Mario play log is missing from the installed "
                "package (was pcpg_dist/data/ left out of the build?)"
            )
        return load_play_log(
            path, strict=strict, goal=goal, increments=increments, event=event, counters=counters
        )


def shipped_log_path() -> Path:
    """Filesystem path of the shipped log (for hashing or copying; the wheel is unzipped)."""
    return Path(str(resources.files(SHIPPED_PACKAGE).joinpath(*SHIPPED_PATH)))


# ------------------------------------------------------------------ valid actions
def valid_mask_from(train: Dataset) -> np.ndarray:
    """(n_actions,) bool: the event ids that occur as a BC target (next event) in ``train``.

    Predicting an event never seen in training can only be a guess, so callers restrict the
    valid set to these (and the random baseline becomes 1 / number of seen events).
    """
    seen = np.unique(train.actions[train.actions >= 0])
    if not len(seen):
        raise DataError(
            f"dataset {train.domain}-{train.env}: no step with an action, "
            "cannot derive a valid-event mask"
        )
    mask = np.zeros(train.n_actions, bool)
    mask[seen] = True
    return mask


def with_valid(dataset: Dataset, mask: np.ndarray) -> Dataset:
    """A copy of ``dataset`` whose every row has the valid-action mask ``mask`` ((n_actions,) bool)."""
    mask = np.asarray(mask, bool)
    if mask.shape != (dataset.n_actions,) or not mask.any():
        raise DataError(
            f"valid mask must be a non-empty ({dataset.n_actions},) bool vector, got "
            f"shape {mask.shape} with {int(mask.sum())} valid"
        )
    return replace(dataset, valid=np.broadcast_to(mask, (dataset.n_rows, dataset.n_actions)).copy())


# ------------------------------------------------------------------ splits
def split_episodes(dataset: Dataset, test_fraction: float, seed: int) -> tuple[Dataset, Dataset]:
    """Seeded (train, test) split by episode: an episode is one trajectory, never cut in two."""
    if not 0.0 < test_fraction < 1.0:
        raise DataError(f"test_fraction must be in (0, 1), got {test_fraction}")
    n = dataset.n_trajectories
    n_test = int(round(test_fraction * n))
    if not 0 < n_test < n:
        raise DataError(f"test_fraction {test_fraction} of {n} episodes leaves an empty part")
    order = np.random.default_rng(seed).permutation(n)
    return dataset.subset(np.sort(order[n_test:])), dataset.subset(np.sort(order[:n_test]))


# ------------------------------------------------------------------ cluster profiles
RATE_COLUMNS = tuple(f"{c}_per_step" for c in COUNTERS)


def cluster_profile(dataset: Dataset, labels: np.ndarray) -> pd.DataFrame:
    """Per cluster: size, mean length, success rate and mean per-step rate of each counter.

    An episode's rate is its final counter (the counters are cumulative from zero) divided by
    its number of steps; the cluster's value is the mean over its episodes, so every episode
    weighs the same whatever its length. This is what a person reads to name a style
    ("jumps twice as often", "dies a lot").
    """
    labels = np.asarray(labels)
    if labels.shape != (dataset.n_trajectories,):
        raise DataError(f"labels must have shape ({dataset.n_trajectories},), got {labels.shape}")
    lengths = dataset.lengths
    names = dataset.feature_names
    if all(c in names for c in COUNTERS):
        cols = [names.index(c) for c in COUNTERS]
        finals = dataset.states[dataset.offsets[1:] - 1][:, cols].astype(np.float64)
    elif all(c in names for c in INCREMENTS):  # a counter's final value is its increments' sum
        cols = [names.index(c) for c in INCREMENTS]
        per_row = dataset.states[:, cols].astype(np.float64)
        finals = np.add.reduceat(per_row, dataset.offsets[:-1], axis=0)
    else:
        raise DataError(
            f"dataset {dataset.domain}-{dataset.env} has neither the Mario counters "
            f"{list(COUNTERS)} nor their increments {list(INCREMENTS)} "
            f"(feature_names={list(names)})"
        )
    frame = pd.DataFrame(finals / lengths[:, None], columns=list(RATE_COLUMNS))
    frame["length"] = lengths
    frame["success"] = dataset.success.astype(np.float64)
    frame["cluster"] = labels
    grouped = frame.groupby("cluster", sort=True)
    profile = grouped[list(RATE_COLUMNS)].mean()
    profile.insert(0, "success_rate", grouped["success"].mean())
    profile.insert(0, "mean_length", grouped["length"].mean())
    profile.insert(0, "size", grouped.size())
    return profile


def plot_profile(profile: pd.DataFrame, path: str | Path) -> Path:
    """Grouped bar chart PNG: each cluster's per-step rates relative to the whole data's mean,
    beside each cluster's mean length (size in the labels). Returns the path written."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    missing = [c for c in (*RATE_COLUMNS, "size", "mean_length") if c not in profile.columns]
    if missing:
        raise DataError(f"profile lacks columns {missing}; build it with cluster_profile()")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sizes = profile["size"].to_numpy(np.float64)
    rates = profile[list(RATE_COLUMNS)].to_numpy(np.float64)
    overall = (rates * sizes[:, None]).sum(axis=0) / max(sizes.sum(), 1.0)
    relative = np.divide(rates, overall, out=np.zeros_like(rates), where=overall > 0)

    fig = Figure(figsize=(10, 4), layout="constrained")
    FigureCanvasAgg(fig)
    ax, ax_len = fig.subplots(1, 2, width_ratios=[3, 1])
    k = len(profile)
    width = 0.8 / max(k, 1)
    x = np.arange(len(COUNTERS))
    names = [f"cluster {c} (n={int(s)})" for c, s in zip(profile.index, sizes, strict=True)]
    for i in range(k):
        ax.bar(
            x + (i - (k - 1) / 2) * width, relative[i], width, label=names[i], color=f"C{i % 10}"
        )
    ax.axhline(1.0, color="black", lw=0.8, ls="--")
    ax.set_xticks(x, [c.replace("_", " ") for c in COUNTERS])
    ax.set_ylabel("per-step rate / all-episode mean")
    ax.set_title("Mario play-style profile")
    ax.legend(fontsize="small")
    ax_len.bar(
        np.arange(k), profile["mean_length"].to_numpy(), color=[f"C{i % 10}" for i in range(k)]
    )
    ax_len.set_xticks(np.arange(k), [str(c) for c in profile.index])
    ax_len.set_xlabel("cluster")
    ax_len.set_ylabel("mean episode length (steps)")
    fig.savefig(path, dpi=100)
    return path
