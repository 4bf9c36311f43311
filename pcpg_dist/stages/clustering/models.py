"""The LSTM sequence autoencoder of Step A, its batching, and the saved cluster model.

Why it looks like this:

- **Batches are built once.** Trajectories are sorted by length and cut into fixed batches, each
  stored as a ready :class:`~torch.nn.utils.rnn.PackedSequence`. Neighbours in length pad nothing,
  packing skips the LSTM work of finished sequences, and no Python runs per sample in an epoch;
  each epoch only shuffles the order of the batches (with a local ``torch.Generator``).
- **Normalisation** is per state feature (mean / std over all rows of the training data), fitted
  once and stored with the model, so ``predict`` sees new trajectories on the training scale.
  Flags such as GridWorld's b1/b2 then weigh as much in the reconstruction as coordinates do.
- **Encoder** = one LSTM layer; its last hidden state (the state after the trajectory's final
  step, which packing gives exactly) goes through a linear layer to the latent ``z``.
  **Decoder** = ``z`` fed at every step to one LSTM layer and a linear read-out: it must rebuild
  the whole sequence from ``z`` alone, so ``z`` has to summarise the route.
- **Assignment** is the nearest centroid in the model's feature space for every method: the
  Student-t soft assignment of DEC is a decreasing function of distance, so its argmax is the
  nearest centroid too. One saved format therefore serves all three methods.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from pydantic import ValidationError
from torch import nn
from torch.nn.utils.rnn import PackedSequence

from pcpg_dist.common.errors import DataError, first_line

FORMAT_VERSION = 1
CONFIG_FILE = "cluster_model.json"
WEIGHTS_FILE = "cluster_model.pt"
#: Methods on visitation bags (pcpg_dist/stages/clustering/features.py): nearest cluster mean in bag space.
BAG_METHODS = ("bag_kmeans", "bag_mop", "bag_auto", "greedy_mix")
#: Bag methods whose model is a mixture of greedy policies (pcpg_dist/stages/clustering/greedy_mix.py)
GREEDY_METHODS = ("bag_auto", "greedy_mix")


# --------------------------------------------------------------------- input checks and features
def checked_sequences(dataset, where: str = "clustering") -> tuple[np.ndarray, np.ndarray]:
    """``(states float32 (rows, d), offsets (n+1,))`` of a dataset, checked for what we rely on.

    The :class:`Dataset` constructor validates too, but its arrays are mutable numpy arrays, so a
    caller can break them afterwards; a NaN reaching the LSTM would silently poison every weight.
    """
    states = np.asarray(dataset.states, dtype=np.float32)
    offsets = np.asarray(dataset.offsets, dtype=np.int64)
    n = len(offsets) - 1
    if n < 1:
        raise DataError(f"{where}: dataset {dataset.domain}-{dataset.env} has no trajectories")
    if states.ndim != 2 or states.shape[1] < 1:
        raise DataError(f"{where}: states must have shape (rows, d>=1), got {states.shape}")
    if (np.diff(offsets) < 1).any() or offsets[0] != 0 or offsets[-1] != len(states):
        raise DataError(
            f"{where}: offsets must rise from 0 to {len(states)}; every trajectory needs a state"
        )
    bad = ~np.isfinite(states)
    if bad.any():
        row = int(np.nonzero(bad.any(axis=1))[0][0])
        traj = int(np.searchsorted(offsets, row, side="right") - 1)
        raise DataError(
            f"{where}: trajectory {traj} (row {row}) has a NaN or infinite state feature"
        )
    return states, offsets


def summary_features(states: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Per trajectory: [length, final state, mean state] — the cheap baseline's whole view."""
    lengths = np.diff(offsets)
    sums = np.add.reduceat(states.astype(np.float64), offsets[:-1], axis=0)
    final = states[offsets[1:] - 1].astype(np.float64)
    return np.column_stack([lengths.astype(np.float64), final, sums / lengths[:, None]])


MAX_VOCAB = 20_000  # visits_kmeans: most frequent distinct states kept as features


def row_ids(states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Id of every distinct state row (0..u-1, in sorted order of a row hash) and each id's first row.

    Rows are hashed by two fixed random projections (a complex number each), then sorted once: a
    million 64-wide rows take a second, where ``np.unique(axis=0)`` takes minutes. Two different
    rows share an id only if both projections collide exactly (never seen; harmless for features).
    """
    x = np.ascontiguousarray(states, np.float64)
    proj = np.random.default_rng(20231013).standard_normal((x.shape[1], 2))
    h = x @ proj
    key = h[:, 0] + 1j * h[:, 1]
    _, first, inv = np.unique(key, return_index=True, return_inverse=True)
    return inv.reshape(-1).astype(np.int64), first


def state_vocabulary(states: np.ndarray) -> np.ndarray:
    """The distinct state rows, most frequent first (at most MAX_VOCAB): visits_kmeans' features."""
    ids, first = row_ids(states)
    counts = np.bincount(ids)
    keep = np.argsort(-counts, kind="stable")[:MAX_VOCAB]
    return np.ascontiguousarray(states, np.float32)[first[keep]]


def visit_features(states: np.ndarray, offsets: np.ndarray, vocab: np.ndarray):
    """(n, V) sparse, rows L2-normalised: which vocabulary states each trajectory visits.

    Binary (visited or not) so a loop walked twice is the same route; normalised so a long
    trajectory and a short one of the same route stay close (cosine geometry for k-means).
    """
    from scipy import sparse
    from sklearn.preprocessing import normalize

    both = np.concatenate([vocab.astype(np.float32), np.asarray(states, np.float32)])
    inv, _ = row_ids(both)
    col_of = np.full(inv.max() + 1, -1, np.int64)
    col_of[inv[: len(vocab)]] = np.arange(len(vocab))
    cols = col_of[inv[len(vocab) :]]
    traj = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    ok = cols >= 0
    m = sparse.csr_matrix(
        (np.ones(int(ok.sum())), (traj[ok], cols[ok])), shape=(len(offsets) - 1, len(vocab))
    )
    m.data[:] = 1.0
    return normalize(m)


def fit_normaliser(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column mean and std; constant columns get std 1 so they stay finite (and stay zero)."""
    mean = x.mean(axis=0)
    std = x.std(axis=0)
    std = np.where(std > 1e-6, std, 1.0)
    return mean.astype(np.float32), std.astype(np.float32)


# --------------------------------------------------------------------- batching
@dataclass(frozen=True)
class PackedBatch:
    """One fixed batch: its trajectories (dataset positions, longest first) and packed states."""

    index: torch.Tensor  # (B,) positions in the dataset
    packed: PackedSequence  # normalised states, time-major packed
    repeat: torch.Tensor  # (rows,) batch slot of every packed row, to feed z at every step
    lengths: torch.Tensor  # (B,) float lengths, longest first


def make_batches(states: np.ndarray, offsets: np.ndarray, batch_size: int) -> list[PackedBatch]:
    """Sort by length (longest first, ties by position) and pack fixed batches of ``batch_size``."""
    lengths = np.diff(offsets)
    order = np.lexsort((np.arange(len(lengths)), -lengths))
    batches = []
    for start in range(0, len(order), batch_size):
        idx = order[start : start + batch_size]
        lens = lengths[idx]
        t_max = int(lens[0])
        # (T, B) mask in C order = time-major, batch slot ascending: exactly PackedSequence layout.
        t_idx, slot = np.nonzero(np.arange(t_max)[:, None] < lens[None, :])
        rows = offsets[idx][slot] + t_idx
        batch_sizes = torch.from_numpy((lens[None, :] > np.arange(t_max)[:, None]).sum(axis=1))
        data = torch.from_numpy(np.ascontiguousarray(states[rows]))
        batches.append(
            PackedBatch(
                torch.from_numpy(idx.copy()),
                PackedSequence(data, batch_sizes),
                torch.from_numpy(slot.astype(np.int64)),
                torch.from_numpy(lens.astype(np.float32)),
            )
        )
    return batches


# --------------------------------------------------------------------- network
class SequenceAutoencoder(nn.Module):
    """LSTM encoder -> latent z -> LSTM decoder that rebuilds the normalised states from z."""

    def __init__(
        self, state_dim: int, hidden_size: int, latent_size: int, pooling: str = "last"
    ) -> None:
        super().__init__()
        if pooling not in ("last", "last_mean"):
            raise DataError(f"unknown encoder pooling '{pooling}' (expected 'last' or 'last_mean')")
        self.pooling = pooling
        self.encoder = nn.LSTM(state_dim, hidden_size)
        self.to_latent = nn.Linear(hidden_size * (2 if pooling == "last_mean" else 1), latent_size)
        self.decoder = nn.LSTM(latent_size, hidden_size)
        self.to_state = nn.Linear(hidden_size, state_dim)

    def reset_parameters(self, generator: torch.Generator) -> None:
        """PyTorch's default init (uniform +-1/sqrt(fan)), drawn from a local generator.

        ``nn.Module`` initialises from the global RNG; redrawing here keeps the stage free of
        global random state, so the same seed gives the same model whatever ran before.
        """
        with torch.no_grad():
            for module in (self.encoder, self.decoder):
                bound = 1.0 / math.sqrt(module.hidden_size)
                for p in module.parameters():
                    p.uniform_(-bound, bound, generator=generator)
            for lin in (self.to_latent, self.to_state):
                bound = 1.0 / math.sqrt(lin.in_features)
                lin.weight.uniform_(-bound, bound, generator=generator)
                lin.bias.uniform_(-bound, bound, generator=generator)

    def encode(self, packed: PackedSequence, batch: PackedBatch | None = None) -> torch.Tensor:
        """Latent z per sequence: from the last hidden state, or (``last_mean``) the last hidden
        state beside the mean hidden state over all steps, which sums up where the route went."""
        out, (h, _) = self.encoder(packed)
        if self.pooling == "last":
            return self.to_latent(h[-1])
        sums = torch.zeros_like(h[-1]).index_add_(0, batch.repeat, out.data)
        return self.to_latent(torch.cat([h[-1], sums / batch.lengths[:, None]], dim=1))

    def decode(self, z: torch.Tensor, batch: PackedBatch) -> torch.Tensor:
        """Reconstructed packed data (rows, d), aligned with ``batch.packed.data``."""
        inp = PackedSequence(z[batch.repeat], batch.packed.batch_sizes)
        out, _ = self.decoder(inp)
        return self.to_state(out.data)


def encode_all(ae: SequenceAutoencoder, batches: list[PackedBatch], n: int) -> torch.Tensor:
    """Latents of every trajectory, in dataset order."""
    device = batches[0].packed.data.device if batches else torch.device("cpu")
    z_all = torch.empty(n, ae.to_latent.out_features, device=device)
    with torch.no_grad():
        for b in batches:
            z_all[b.index] = ae.encode(b.packed, b)
    return z_all


def batches_to(batches: list[PackedBatch], device: torch.device) -> list[PackedBatch]:
    """The same batches on ``device`` (PackedSequence's batch_sizes stay on the CPU, as torch wants)."""
    if device.type == "cpu":
        return batches
    return [
        PackedBatch(
            b.index.to(device),
            PackedSequence(b.packed.data.to(device), b.packed.batch_sizes),
            b.repeat.to(device),
            b.lengths.to(device),
        )
        for b in batches
    ]


# --------------------------------------------------------------------- the saved model
class PolicyMixture(nn.Module):
    """k policies pi_c(a | s) over one shared tanh MLP trunk: k softmax heads of n_actions logits.

    ``policy_mix`` clusters with it: a trajectory's score for cluster c is log prior_c plus the sum
    of log pi_c(a_t | s_t) over its steps (the transitions are the same for every style, so they
    cancel). The states are normalised with the training mean/std before the trunk.
    """

    def __init__(self, state_dim: int, hidden_size: int, k: int, n_actions: int) -> None:
        super().__init__()
        self.k, self.n_actions = int(k), int(n_actions)
        self.trunk = nn.Sequential(
            nn.Linear(state_dim, hidden_size),
            nn.Tanh(),
            nn.Linear(hidden_size, hidden_size),
            nn.Tanh(),
        )
        self.heads = nn.Linear(hidden_size, self.k * self.n_actions)
        self.register_buffer("log_prior", torch.full((self.k,), -math.log(self.k)))

    def reset_parameters(self, generator: torch.Generator) -> None:
        """PyTorch's default init, drawn from a local generator (see SequenceAutoencoder)."""
        with torch.no_grad():
            for lin in (self.trunk[0], self.trunk[2], self.heads):
                bound = 1.0 / math.sqrt(lin.in_features)
                lin.weight.uniform_(-bound, bound, generator=generator)
                lin.bias.uniform_(-bound, bound, generator=generator)

    def step_log_probs(
        self, states: torch.Tensor, actions: torch.Tensor, valid: torch.Tensor
    ) -> torch.Tensor:
        """(k, rows): log pi_c(a_t | s_t) of every step under every head, invalid actions masked."""
        logits = self.heads(self.trunk(states)).view(len(states), self.k, self.n_actions)
        logits = logits.permute(1, 0, 2).masked_fill(~valid, -1e9)
        picked = actions.expand(self.k, -1).unsqueeze(-1)
        return torch.log_softmax(logits, -1).gather(2, picked).squeeze(-1)


def policy_inputs(dataset, states: np.ndarray, mean: np.ndarray, std: np.ndarray):
    """The steps a policy mixture scores: normalised states, actions, valid masks, trajectory index.

    Only rows with an action (every row but a trajectory's last); a taken action always counts as
    valid, so a log whose valid mask disagrees with its actions cannot give -inf scores.
    """
    actions = np.asarray(dataset.actions, np.int64)
    n_actions = int(dataset.n_actions)
    rows = np.flatnonzero(actions >= 0)
    if rows.size and actions[rows].max() >= n_actions:
        raise DataError(
            f"{dataset.domain}-{dataset.env}: action {int(actions[rows].max())} "
            f"outside 0..{n_actions - 1}"
        )
    valid = np.asarray(dataset.valid, bool)[rows].copy()
    valid[np.arange(rows.size), actions[rows]] = True
    traj = dataset.row_trajectory[rows]
    norm = ((states[rows] - mean) / std).astype(np.float32)
    return (
        torch.from_numpy(norm),
        torch.from_numpy(actions[rows]),
        torch.from_numpy(valid),
        torch.from_numpy(traj),
    )


def trajectory_scores(policy: PolicyMixture, inputs, n: int) -> torch.Tensor:
    """(k, n): log prior + summed step log-likelihood of each trajectory under each policy."""
    s, a, valid, traj = inputs
    lp = policy.step_log_probs(s, a, valid)
    return (
        torch.zeros(policy.k, n, device=lp.device).index_add_(1, traj, lp)
        + policy.log_prior[:, None]
    )


class ClusterModel:
    """A fitted clusterer: feature pipeline + centroids; assigns trajectories to styles.

    ``method`` is ``lstm_dec`` / ``lstm_kmeans`` (features = encoder latents of normalised states),
    ``summary_kmeans`` (features = normalised :func:`summary_features`), ``visits_kmeans`` / the
    ``bag_*`` methods (visitation features), or ``policy_mix`` (features = the posterior over the
    k policies of :class:`PolicyMixture`; centroids = the identity, so nearest = most likely).
    """

    def __init__(
        self,
        method: str,
        config: dict,
        state_dim: int,
        mean: np.ndarray,
        std: np.ndarray,
        centroids: np.ndarray,
        autoencoder: SequenceAutoencoder | None,
        feature_names: tuple[str, ...] = (),
        vocabulary: np.ndarray | None = None,
        bag=None,
        policy: PolicyMixture | None = None,
        greedy: tuple[np.ndarray, np.ndarray, float] | None = None,
    ) -> None:
        self.method = method
        self.config = dict(config)
        self.state_dim = int(state_dim)
        self.mean = np.asarray(mean, np.float32)
        self.std = np.asarray(std, np.float32)
        self.centroids = np.asarray(centroids, np.float32)
        self.autoencoder = autoencoder
        self.feature_names = tuple(feature_names)
        self.vocabulary = None if vocabulary is None else np.asarray(vocabulary, np.float32)
        self.bag = (
            bag  # BagVocabulary of the bag_* methods (pcpg_dist/stages/clustering/features.py)
        )
        self.policy = policy  # policy_mix: k policies; features = posteriors, centroids = I_k
        # greedy_mix / bag_auto: (votes (k, V, A) over the bag's states, log cluster shares, noise)
        self.greedy = (
            None
            if greedy is None
            else (
                np.asarray(greedy[0], np.float64),
                np.asarray(greedy[1], np.float64),
                float(greedy[2]),
            )
        )

    @property
    def k(self) -> int:
        return int(self.centroids.shape[0])

    def _checked_states(self, dataset) -> tuple[np.ndarray, np.ndarray]:
        """``dataset``'s (states, offsets), checked, with as many state features as the model's."""
        states, offsets = checked_sequences(dataset, where=f"{self.method} model")
        if states.shape[1] != self.state_dim:
            raise DataError(
                f"{self.method} model was fitted on {self.state_dim} state features, "
                f"dataset {dataset.domain}-{dataset.env} has {states.shape[1]}"
            )
        return states, offsets

    def features(self, dataset) -> np.ndarray:
        """The space the centroids live in: latents (LSTM methods) or normalised summaries."""
        states, offsets = self._checked_states(dataset)
        if self.bag is not None:
            from sklearn.preprocessing import normalize

            from pcpg_dist.stages.clustering.features import bag_matrix

            actions = np.asarray(dataset.actions, np.int64)
            return normalize(bag_matrix(states, offsets, actions, self.bag))
        if self.vocabulary is not None:
            return visit_features(states, offsets, self.vocabulary)
        if self.policy is not None:
            if int(dataset.n_actions) != self.policy.n_actions:
                raise DataError(
                    f"policy_mix model was fitted on {self.policy.n_actions} actions, "
                    f"dataset {dataset.domain}-{dataset.env} has {dataset.n_actions}"
                )
            inputs = policy_inputs(dataset, states, self.mean, self.std)
            with torch.no_grad():
                scores = trajectory_scores(self.policy, inputs, len(offsets) - 1)
            return torch.softmax(scores, 0).T.numpy().astype(np.float32)
        if self.autoencoder is None:
            return ((summary_features(states, offsets) - self.mean) / self.std).astype(np.float32)
        norm = (states - self.mean) / self.std
        batches = make_batches(norm, offsets, int(self.config.get("batch_size", 512)))
        self.autoencoder.eval()
        return encode_all(self.autoencoder, batches, len(offsets) - 1).numpy()

    def assign(self, feats: np.ndarray) -> np.ndarray:
        """Nearest centroid (= argmax of DEC's Student-t assignment); ties go to the lower index."""
        if not isinstance(feats, np.ndarray):  # sparse visit features: |x|^2 - 2 x.c + |c|^2
            c = self.centroids.astype(np.float64)
            d2 = -2 * np.asarray(feats @ c.T) + (c**2).sum(axis=1)[None]
            return np.argmin(d2, axis=1).astype(np.int64)
        d2 = (
            (feats[:, None, :].astype(np.float64) - self.centroids[None].astype(np.float64)) ** 2
        ).sum(-1)
        return np.argmin(d2, axis=1).astype(np.int64)

    def predict(self, dataset) -> np.ndarray:
        """Cluster label (0..k-1) of every trajectory of ``dataset``."""
        if self.greedy is not None:
            return self._greedy_predict(dataset)
        return self.assign(self.features(dataset))

    def unknown_rows(self, dataset) -> float | None:
        """Fraction of ``dataset``'s rows whose state is not among the states the model was fitted
        on (``None`` for models of continuous states). Those rows say nothing to a bag model, so
        a high fraction means another layout or game than the one it was fitted on."""
        if self.bag is None:
            return None
        from pcpg_dist.stages.clustering.features import _state_columns

        states, _ = self._checked_states(dataset)
        return float((_state_columns(states, self.bag.states) < 0).mean())

    def _greedy_predict(self, dataset) -> np.ndarray:
        from pcpg_dist.stages.clustering import greedy_mix

        states, _ = self._checked_states(dataset)
        votes, log_share, noise = self.greedy
        if int(dataset.n_actions) != votes.shape[2]:
            raise DataError(
                f"{self.method} model was fitted on {votes.shape[2]} actions, "
                f"dataset {dataset.domain}-{dataset.env} has {dataset.n_actions}"
            )
        return greedy_mix.predict(
            greedy_mix.Steps.of_dataset(dataset, states, self.bag.states), votes, log_share, noise
        )

    # ------------------------------------------------------------- persistence
    def save(self, directory: str | Path) -> Path:
        """Write ``cluster_model.json`` (method, config, shapes) and ``cluster_model.pt`` (tensors)."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        tensors = {
            "mean": torch.from_numpy(self.mean),
            "std": torch.from_numpy(self.std),
            "centroids": torch.from_numpy(self.centroids),
        }
        if self.vocabulary is not None:
            tensors["vocabulary"] = torch.from_numpy(self.vocabulary)
        if self.bag is not None:
            tensors["bag_states"] = torch.from_numpy(self.bag.states)
            tensors["bag_sa_keys"] = torch.from_numpy(self.bag.sa_keys)
        if self.autoencoder is not None:
            tensors.update(
                {f"ae.{k}": v.detach().clone() for k, v in self.autoencoder.state_dict().items()}
            )
        if self.policy is not None:
            tensors.update(
                {f"pm.{k}": v.detach().clone() for k, v in self.policy.state_dict().items()}
            )
        if self.greedy is not None:
            tensors["greedy_votes"] = torch.from_numpy(self.greedy[0])
            tensors["greedy_log_share"] = torch.from_numpy(self.greedy[1])
            tensors["greedy_noise"] = torch.tensor([self.greedy[2]], dtype=torch.float64)
        torch.save(tensors, directory / WEIGHTS_FILE)
        meta = {
            "format_version": FORMAT_VERSION,
            "method": self.method,
            "config": self.config,
            "state_dim": self.state_dim,
            "k": self.k,
            "feature_names": list(self.feature_names),
        }
        if self.bag is not None:
            meta["bag_n_actions"] = self.bag.n_actions
        if self.policy is not None:
            meta["n_actions"] = self.policy.n_actions
        (directory / CONFIG_FILE).write_text(json.dumps(meta, indent=2, sort_keys=True))
        return directory


TORCH_UNREADABLE = "not a pcpg model file (torch could not read its tensors)"
#: dtypes a saved tensor may have: real floats for values, integers for keys
_FLOATS, _INTS = (torch.float32, torch.float64), (torch.int64, torch.int32)
MAX_K = 1000  # as ClusterConfig.k and tuning.k_range allow


def read_tensors(path: Path, what: str = "") -> dict[str, torch.Tensor]:
    """The named tensors of a file written by ``torch.save``: read with ``weights_only=True``
    (nothing is unpickled) and torch's warnings silenced; any other content is a one-line
    ``DataError`` that never repeats torch's advice to load with ``weights_only=False``."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            obj = torch.load(path, weights_only=True, map_location="cpu")
    except OSError as e:
        raise DataError(f"{path}: {what}cannot read it ({first_line(e)})") from None
    except Exception:  # noqa: BLE001 - UnpicklingError, EOFError, RuntimeError, ...: not our format
        raise DataError(f"{path}: {what}{TORCH_UNREADABLE}") from None
    if not isinstance(obj, dict) or not all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in obj.items()
    ):
        raise DataError(
            f"{path}: {what}not a pcpg model file (it holds a {type(obj).__name__}, "
            f"not named tensors)"
        )
    return obj


def _dtype(dtype: torch.dtype) -> str:
    return str(dtype).removeprefix("torch.")


class _Weights:
    """Checks the tensors of one ``cluster_model.pt`` against what its method needs."""

    def __init__(self, path: Path, method: str, tensors: dict[str, torch.Tensor]) -> None:
        self.path, self.method, self.tensors = path, method, tensors

    def fail(self, text: str) -> DataError:
        return DataError(f"{self.path}: {text}")

    def get(
        self, name: str, shape: tuple[int | None, ...], dtypes=_FLOATS, finite: bool = True
    ) -> torch.Tensor:
        """``name``, present, of one of ``dtypes`` and of ``shape`` (None: any size there)."""
        t = self.tensors.get(name)
        if t is None:
            raise self.fail(f"no tensor '{name}', which a {self.method} model needs")
        if t.dtype not in dtypes:
            raise self.fail(
                f"{name} has dtype {_dtype(t.dtype)}; a {self.method} model stores "
                + " or ".join(_dtype(d) for d in dtypes)
            )
        if t.ndim != len(shape) or any(
            w is not None and w != n for w, n in zip(shape, t.shape, strict=True)
        ):
            want = ", ".join("any" if w is None else str(w) for w in shape)
            want = f"({want},)" if len(shape) == 1 else f"({want})"
            raise self.fail(
                f"{name} has shape {tuple(t.shape)}; a {self.method} model needs {want}"
            )
        if finite and t.is_floating_point() and not bool(torch.isfinite(t).all()):
            raise self.fail(f"{name} has non-finite values (NaN or inf); all must be finite")
        return t

    def module(self, make, prefix: str, sizes: str) -> nn.Module:
        """``make()`` loaded with the ``prefix``-named tensors, once they are checked against the
        shapes its state dict has (they follow from ``sizes``, the JSON's settings named in the
        message). The shapes come from a ``meta``-device copy, so a JSON asking for a huge network
        allocates nothing before it is refused."""
        sd = _shapes(make)
        for name, shape in sd.items():
            try:
                self.get(prefix + name, shape)
            except DataError as e:  # the sizes come from the JSON: say so
                raise DataError(f"{e} (from {sizes} in {CONFIG_FILE})") from None
        module = make()
        module.load_state_dict({n: self.tensors[prefix + n].to(torch.float32) for n in sd})
        return module


def _shapes(make) -> dict[str, tuple[int, ...]]:
    """Names and shapes of the state dict of the module ``make()`` builds, with no memory."""
    with torch.device("meta"):
        return {n: tuple(t.shape) for n, t in make().state_dict().items()}


def load_model(directory: str | Path) -> ClusterModel:
    """Read a model written by :meth:`ClusterModel.save` (tensors only: ``weights_only=True``).

    Every tensor is checked against ``cluster_model.json`` before anything is built: the method's
    tensors and no others, their dtypes, shapes (k centroids of the method's feature width),
    finite values and ranges (std > 0, state-action keys within the bag), so a tampered or
    mismatched file is a one-line :class:`DataError` naming the file and field, never a traceback
    or a model that silently gives other labels.
    """
    directory = Path(directory)
    cfg_path, w_path = directory / CONFIG_FILE, directory / WEIGHTS_FILE
    for p in (cfg_path, w_path):
        if not p.is_file():
            raise DataError(
                f"{p}: cluster model file not found (is {directory} a saved cluster model?)"
            )
    try:
        if cfg_path.stat().st_size > 1 << 20:
            raise ValueError("larger than 1 MB")
        meta = json.loads(cfg_path.read_text(encoding="utf-8"))
        method, config, state_dim, k = meta["method"], meta["config"], meta["state_dim"], meta["k"]
        if not isinstance(config, dict) or not isinstance(method, str):
            raise TypeError("'method' must be a name and 'config' a mapping")
        if type(state_dim) is not int or not 1 <= state_dim <= 1_000_000:
            raise ValueError(f"state_dim {state_dim!r}; expected an integer in 1..1000000")
        if type(k) is not int or not 1 <= k <= MAX_K:
            raise ValueError(f"k {k!r}; expected an integer in 1..{MAX_K}")
        names = meta.get("feature_names") or []
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise TypeError("'feature_names' must be a list of names")
        # the saved settings must be settings Step A accepts (bounded sizes, known method)
        from pcpg_dist.config.stages import ClusterConfig

        known = {k: v for k, v in config.items() if k in ClusterConfig.model_fields}
        try:
            settings = ClusterConfig.model_validate(known)
        except ValidationError as e:
            first = e.errors(include_url=False)[0]
            raise ValueError(f"config.{'.'.join(map(str, first['loc']))}: {first['msg']}") from None
    except (
        ValueError,
        KeyError,
        TypeError,
        OverflowError,
        RecursionError,
        UnicodeDecodeError,
    ) as e:
        raise DataError(
            f"{cfg_path}: unreadable cluster model config ({' '.join(str(e).split())[:200]})"
        ) from None
    if meta.get("format_version") != FORMAT_VERSION:
        raise DataError(
            f"{cfg_path}: format_version {meta.get('format_version')!r}, expected {FORMAT_VERSION}"
        )
    known_methods = (
        "lstm_dec",
        "lstm_kmeans",
        "summary_kmeans",
        "visits_kmeans",
        "policy_mix",
        *BAG_METHODS,
    )
    if method not in known_methods:
        raise DataError(f"{cfg_path}: unknown clustering method {method!r}")
    key = (
        "n_actions"
        if method == "policy_mix"
        else "bag_n_actions"
        if method in BAG_METHODS
        else None
    )
    if key is not None and (type(meta.get(key)) is not int or not 1 <= meta[key] <= 1_000_000):
        raise DataError(
            f"{cfg_path}: {key} {meta.get(key)!r}; a {method} model needs an integer in 1..1000000"
        )
    tensors = read_tensors(w_path)
    w = _Weights(w_path, method, tensors)
    d = state_dim

    # the method's modules fix the names and shapes of their tensors
    make_ae = make_policy = None
    if method in ("lstm_dec", "lstm_kmeans"):

        def make_ae():
            return SequenceAutoencoder(
                d, settings.hidden_size, settings.latent_size, settings.pooling
            )

    if method == "policy_mix":

        def make_policy():
            return PolicyMixture(d, settings.hidden_size, k, meta["n_actions"])

    extra = {"visits_kmeans": {"vocabulary"}}.get(method, set())
    if method in BAG_METHODS:
        extra = {"bag_states", "bag_sa_keys"}
    if method in GREEDY_METHODS:
        extra |= {"greedy_votes", "greedy_log_share", "greedy_noise"}
    if make_ae is not None:
        extra = {"ae." + n for n in _shapes(make_ae)}
    if make_policy is not None:
        extra = {"pm." + n for n in _shapes(make_policy)}
    foreign = sorted(set(tensors) - {"mean", "std", "centroids"} - extra)
    if foreign:
        raise w.fail(
            f"holds tensor '{foreign[0]}', which a {method} model (the method in "
            f"{CONFIG_FILE}) does not have"
        )

    # feature width: where the centroids live
    width = None
    if method == "summary_kmeans":
        width = 1 + 2 * d
    elif make_ae is not None:
        width = settings.latent_size
    elif make_policy is not None:
        width = k
    vocab = bag = greedy = None
    if method == "visits_kmeans":
        vocab = w.get("vocabulary", (None, d))
        if not 1 <= vocab.shape[0] <= MAX_VOCAB:
            raise w.fail(
                f"vocabulary has {vocab.shape[0]} states; a visits_kmeans model has 1..{MAX_VOCAB}"
            )
        width = vocab.shape[0]
    if method in BAG_METHODS:
        from pcpg_dist.stages.clustering.features import MAX_STATES, BagVocabulary

        n_actions = meta["bag_n_actions"]
        bs = w.get("bag_states", (None, d))
        if not 1 <= bs.shape[0] <= MAX_STATES:
            raise w.fail(
                f"bag_states has {bs.shape[0]} states; a {method} model has 1..{MAX_STATES}"
            )
        keys = w.get("bag_sa_keys", (None,), _INTS).numpy().astype(np.int64)
        top = bs.shape[0] * n_actions
        if keys.size and (keys.min() < 0 or keys.max() >= top):
            bad = int(keys.min() if keys.min() < 0 else keys.max())
            raise w.fail(
                f"bag_sa_keys holds {bad}, outside 0..{top - 1} (bag_states x bag_n_actions "
                f"{n_actions} in {CONFIG_FILE})"
            )
        if (np.diff(keys) <= 0).any():
            raise w.fail("bag_sa_keys must be strictly increasing")
        bag = BagVocabulary(np.ascontiguousarray(bs.numpy(), np.float32), keys, n_actions)
        width = bag.width
    if method in GREEDY_METHODS:
        gv = w.get("greedy_votes", (k, len(bag.states), bag.n_actions))
        gs = w.get("greedy_log_share", (k,))
        ge = w.get("greedy_noise", (1,))
        if bool((gv < 0).any()):
            raise w.fail("greedy_votes has negative values; votes are counts, 0 or more")
        if not 0.0 < float(ge[0]) < 1.0:
            raise w.fail(f"greedy_noise is {float(ge[0])}; it lies strictly between 0 and 1")
        greedy = (gv.numpy(), gs.numpy(), float(ge[0]))

    feat = 1 + 2 * d if method == "summary_kmeans" else d
    mean = w.get("mean", (feat,)).numpy()
    std = w.get("std", (feat,)).numpy()
    if not (std > 0).all():
        raise w.fail(f"std has a value of {float(std.min())}; standard deviations are above 0")
    c = tensors.get("centroids")
    if c is not None and c.ndim == 2 and c.shape[0] != k:
        raise DataError(f"{cfg_path}: k {k}, but {WEIGHTS_FILE} holds {c.shape[0]} centroids")
    centroids = w.get("centroids", (k, width)).numpy()
    if make_policy is not None and not np.array_equal(centroids, np.eye(k)):
        raise w.fail("centroids of a policy_mix model are the k x k identity")
    ae = policy = None
    if make_ae is not None:
        ae = w.module(
            make_ae, "ae.", "state_dim, config.hidden_size, config.latent_size and config.pooling"
        )
    if make_policy is not None:
        policy = w.module(make_policy, "pm.", "state_dim, config.hidden_size, k and n_actions")
    return ClusterModel(
        method,
        config,
        state_dim,
        mean,
        std,
        centroids,
        ae,
        tuple(meta.get("feature_names") or ()),
        None if vocab is None else vocab.numpy(),
        bag,
        policy,
        greedy,
    )
