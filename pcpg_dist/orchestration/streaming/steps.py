"""Step A and Step B over blocks: per-trajectory features, the k-means fit, each trajectory's
cluster, split and top-p code, and the step rows tagged with their trajectory's code."""

from __future__ import annotations

import numpy as np

from pcpg_dist.common.errors import DataError
from pcpg_dist.domains.base import StreamSource
from pcpg_dist.orchestration.streaming.engine import map_blocks, read_steps, reduce_blocks
from pcpg_dist.stages.streamed import cells as P
from pcpg_dist.stages.streamed import features as F
from pcpg_dist.stages.streamed import kmeans as K
from pcpg_dist.stages.streamed import ranking as R

SAMPLE = 20_000  # trajectories the k-means starts are fitted on


def feature_table(source: StreamSource):
    """Per-trajectory features (``x``, ``trajectory``, ``length``, ``ret``, ``style``),
    materialised; and the state columns' mean and scale for the policies' inputs."""
    from ray.data.aggregate import Max, Sum

    d, a = len(source.states), source.n_actions
    columns = ["trajectory", "action", *source.states]
    columns += [c for c in ("reward", "style") if c in source.optional]
    summed_cols = F.partial_columns(d, a)
    partials = map_blocks(
        read_steps(source, columns),
        F.step_partials,
        fn_kwargs={"states": source.states, "n_actions": a},
        batch_size=None,
    )
    partitions = max(2, min(200, source.steps // 1_000_000))
    summed = partials.groupby("trajectory", num_partitions=partitions).aggregate(
        *[Sum(c, alias_name=c) for c in summed_cols], Max("style", alias_name="style")
    )
    summed = summed.materialize()
    state = reduce_blocks(summed, _state_moments, d=d)
    rows = max(state[0], 1.0)
    mean = state[1 : 1 + d] / rows
    scale = np.sqrt(np.maximum(state[1 + d :] / rows - mean * mean, 0.0))
    feats = map_blocks(
        summed, F.trajectory_features, fn_kwargs={"d": d, "n_actions": a}
    ).materialize()
    return feats, mean.astype(np.float32), np.where(scale > 1e-8, scale, 1.0).astype(np.float32)


def _state_moments(batch: dict[str, np.ndarray], d: int) -> np.ndarray:
    return np.concatenate(
        [[batch["rows"].sum()]]
        + [[batch[f"sum{j}"].sum() for j in range(d)], [batch[f"sq{j}"].sum() for j in range(d)]]
    )


def fit_kmeans(feats, k: int, seed: int, max_iter: int = 30, tol: float = 1e-4):
    """Standardise, start from k-means++ on a seeded sample, then Lloyd passes over every block.
    Returns (mean, scale, centres, iterations)."""
    total = reduce_blocks(feats, lambda b: K.moments(b["x"]))
    mean, scale = K.scaling(total)
    n = int(total[0])
    if n < k:
        raise DataError(f"the log holds {n} trajectories; clustering.k = {k} needs at least {k}")
    share = min(1.0, 2 * SAMPLE / n)

    def sample(batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        u = R.uniform(batch["trajectory"], seed, 2)
        keep = u < share
        return {"u": u[keep], "z": ((batch["x"][keep] - mean) / scale).astype(np.float64)}

    found = list(map_blocks(feats, sample).iter_batches(batch_format="numpy", batch_size=None))
    # ordered by the hash, not by arrival: the same sample, in the same order, however the log
    # is cut into blocks and files
    u = np.concatenate([b["u"] for b in found])
    z = np.concatenate([b["z"] for b in found])[np.argsort(u, kind="stable")][:SAMPLE]
    centres = K.initial_centres(z, k, seed)
    for it in range(1, max_iter + 1):  # noqa: B007 - the count is returned
        stats = reduce_blocks(feats, lambda b, c=centres: K.lloyd_stats((b["x"] - mean) / scale, c))
        centres, _, move = K.lloyd_update(centres, stats)
        if move < tol:
            break
    return mean, scale, centres, it


def _score(batch: dict[str, np.ndarray], score: str) -> np.ndarray:
    """Step B's score: the return, or the length (``-length``: shorter is better)."""
    if score == "return":
        return batch["ret"]
    length = batch["length"].astype(np.float64)
    return -length if score == "-length" else length


def label_table(feats, mean, scale, centres, seed: int, cfg, source: StreamSource):
    """Cluster, split and top-p codes of every trajectory (materialised), and the clustering's
    contingency against the true styles (where the log has them)."""
    k = len(centres)
    ps = tuple(cfg.ranking.ps)
    split_seed, test_fraction = cfg.ranking.split_seed, cfg.ranking.test_fraction

    def base(batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        tid = batch["trajectory"]
        test = R.is_test(tid, split_seed, test_fraction)
        return {
            "trajectory": tid,
            "cluster": K.assign((batch["x"] - mean) / scale, centres).astype(np.int64),
            "test": test,
            "validation": R.is_validation(tid, split_seed, 0.1) & ~test,
            "score": _score(batch, source.score),
            "style": batch["style"],
        }

    labelled = map_blocks(feats, base).materialize()
    cuts = top_p_cuts(labelled, k, ps, split_seed)

    def coded(batch):
        tie = R.uniform(batch["trajectory"], split_seed, 3)
        kc, kn = [], []
        for cut_score, cut_tie in cuts:
            c = batch["cluster"]
            kc.append(R.is_kept(batch["score"], tie, cut_score[c], cut_tie[c]))
            kn.append(R.is_kept(batch["score"], tie, cut_score[k], cut_tie[k]))
        code = P.code_of(batch["cluster"], batch["test"], batch["validation"], kc, kn)
        return {**batch, "code": code}

    labels = map_blocks(labelled, coded).materialize()
    contingency = style_contingency(labels, k, "cluster") if "style" in source.optional else None
    return labels, contingency


def style_contingency(labels, k: int, column: str) -> np.ndarray:
    """(true styles present) x k counts of the trajectories with a known style, over blocks."""

    def table(batch):  # (styles seen in this block) x k counts, flattened
        known = batch["style"] >= 0
        cell = batch["style"][known] * k + batch[column][known]
        return np.bincount(cell, minlength=k).astype(np.float64)

    counts = reduce_blocks(labels, table, combine=_padded_add)
    contingency = np.pad(counts, (0, -len(counts) % k)).reshape(-1, k)
    return contingency[contingency.sum(1) > 0]


def classify_log(source: StreamSource, model):
    """Each trajectory of ``source`` under a streamed run's k-means (``model``, a
    :class:`~pcpg_dist.stages.streamed.model.StreamedModel`): the labels (``trajectory``,
    ``predicted_style``, ``style``) materialised in the object store, the cluster sizes, and the
    contingency against the log's styles (None where it has none). The features are the run's,
    built block by block as in :func:`feature_table`."""
    feats, _, _ = feature_table(source)
    mean, scale, centres = model.arrays()

    def label(batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {
            "trajectory": batch["trajectory"],
            "predicted_style": K.assign((batch["x"] - mean) / scale, centres).astype(np.int64),
            "style": batch["style"],
        }

    labels = map_blocks(feats, label).materialize()
    sizes = reduce_blocks(
        labels, lambda b: np.bincount(b["predicted_style"], minlength=model.k).astype(np.float64)
    )
    has_styles = "style" in source.optional
    contingency = style_contingency(labels, model.k, "predicted_style") if has_styles else None
    return labels, sizes, contingency


def _grouped(batch: dict[str, np.ndarray], k: int):
    """The training trajectories' scores twice: by cluster, and all as group k (No Clustering)."""
    train = ~batch["test"]
    s = batch["score"][train]
    ids = batch["trajectory"][train]
    return np.r_[s, s], np.r_[batch["cluster"][train], np.full(len(s), k)], np.r_[ids, ids]


def top_p_cuts(labelled, k: int, ps: tuple[float, ...], split_seed: int) -> list:
    """Per p, the (score, tie-break) cut of every cluster and of No Clustering (group k): three
    passes over the training trajectories' scores (ranges, histograms, the boundary bins)."""
    groups = k + 1

    def ranges(batch):
        s, g, _ = _grouped(batch, k)
        return R.score_ranges(s, g, groups)

    span = reduce_blocks(labelled, ranges, combine=R.merge_ranges)
    lo, hi = span[:groups], span[groups:]

    def histogram(batch):
        s, g, _ = _grouped(batch, k)
        return R.score_histogram(s, g, lo, hi)

    hist = reduce_blocks(labelled, histogram)
    bounds = [R.boundaries(hist, groups, p) for p in ps]
    if all((where < 0).all() for where, _ in bounds):
        return [
            R.exact_cuts(np.empty(0), np.empty(0), np.empty(0, int), need) for _, need in bounds
        ]

    def boundary_rows(batch):
        s, g, ids = _grouped(batch, k)
        b = R.bins_of(s, g, lo, hi)
        rows = [(pi, (b == where[g]) & (where[g] >= 0)) for pi, (where, _) in enumerate(bounds)]
        return {
            "p": np.concatenate([np.full(m.sum(), pi) for pi, m in rows]),
            "group": np.concatenate([g[m] for _, m in rows]),
            "score": np.concatenate([s[m] for _, m in rows]),
            "tie": np.concatenate([R.uniform(ids[m], split_seed, 3) for _, m in rows]),
        }

    found = [
        b
        for b in map_blocks(labelled, boundary_rows).iter_batches(
            batch_format="numpy", batch_size=None
        )
    ]
    cols = {c: np.concatenate([b[c] for b in found]) for c in ("p", "group", "score", "tie")}
    cuts = []
    for pi, (_, need) in enumerate(bounds):
        mine = cols["p"] == pi
        cuts.append(R.exact_cuts(cols["score"][mine], cols["tie"][mine], cols["group"][mine], need))
    return cuts


def _padded_add(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The sum of two count vectors of different lengths (blocks see different styles)."""
    if len(a) < len(b):
        a, b = b, a
    out = a.copy()
    out[: len(b)] += b
    return out


def clustering_quality(contingency: np.ndarray | None) -> dict[str, float]:
    """Accuracy (best one-to-one matching of clusters to styles) and ARI from the contingency."""
    if contingency is None or contingency.sum() == 0:
        return {}
    from scipy.optimize import linear_sum_assignment
    from scipy.special import comb

    rows, cols = linear_sum_assignment(-contingency)
    n = contingency.sum()
    pairs = comb(contingency, 2).sum()
    a, b = comb(contingency.sum(1), 2).sum(), comb(contingency.sum(0), 2).sum()
    expected = a * b / comb(n, 2)
    ari = (pairs - expected) / (0.5 * (a + b) - expected) if a + b != 2 * expected else 1.0
    return {
        "clustering/accuracy": float(contingency[rows, cols].sum() / n),
        "clustering/ari": float(ari),
    }


def lookup_of(labels):
    """(sorted trajectory ids, their codes), assembled in a task and kept in the object store."""
    import ray

    refs = labels.select_columns(["trajectory", "code"]).to_numpy_refs()

    @ray.remote(num_cpus=1)
    def assemble(*parts):
        ids = np.concatenate([p["trajectory"] for p in parts])
        codes = np.concatenate([p["code"] for p in parts])
        order = np.argsort(ids, kind="stable")
        return ids[order], codes[order]

    return assemble.remote(*refs)


def tagged_rows(source: StreamSource, lookup, mean: np.ndarray, scale: np.ndarray, test: bool):
    """The acted steps of the training (``test=False``) or held-out trajectories as
    (standardised state ``x``, action ``y``, its trajectory's ``code``), lazily."""

    def tag(batch: dict[str, np.ndarray], lookup) -> dict[str, np.ndarray]:
        import ray

        ids, codes = ray.get(lookup)
        code = codes[np.searchsorted(ids, batch["trajectory"])]
        keep = (batch["action"] >= 0) & (((code & P.TEST) != 0) == test)
        x = np.stack([batch[c][keep] for c in source.states], 1).astype(np.float32)
        return {
            "x": (x - mean) / scale,
            "y": batch["action"][keep].astype(np.int16),
            "code": code[keep],
        }

    return map_blocks(
        read_steps(source, ["trajectory", "action", *source.states]),
        tag,
        fn_kwargs={"lookup": lookup},
        batch_size=None,
    )
