"""The fitted cluster model of Step A: the feature pipeline of its method, k centroids, and how it
assigns (new) trajectories to styles and saves itself (reading it back: :mod:`.model_io`).

**Assignment** is the nearest centroid in the model's feature space for every method: the
Student-t soft assignment of DEC is a decreasing function of distance, so its argmax is the nearest
centroid too. One saved format therefore serves all methods; greedy_mix and bag_auto assign by
their mixture of greedy policies instead.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from sklearn.preprocessing import normalize

from pcpg_dist.common.errors import DataError
from pcpg_dist.stages.clustering import greedy_mix
from pcpg_dist.stages.clustering.autoencoder import SequenceAutoencoder, encode_all, make_batches
from pcpg_dist.stages.clustering.features import bag_matrix
from pcpg_dist.stages.clustering.policy_network import (
    PolicyMixture,
    policy_inputs,
    policy_states,
    posteriors,
    trajectory_scores,
)
from pcpg_dist.stages.clustering.states import (
    checked_sequences,
    state_columns,
    summary_features,
    visit_features,
)

FORMAT_VERSION = 1


CONFIG_FILE = "cluster_model.json"


WEIGHTS_FILE = "cluster_model.pt"


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
        choice: tuple[np.ndarray, np.ndarray] | None = None,
        move_features: str | None = None,
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

        # choice_mix: the move-feature function it calls, as its fit or its reader was given it
        # (never read from a model file: model_io.load_model)
        self.move_features = move_features
        # choice_mix: (preferences (k, F), log shares (k,)); mean and std standardise the F move
        # features of clustering.move_features; features = posteriors, centroids = I_k
        self.choice = (
            None
            if choice is None
            else (np.asarray(choice[0], np.float64), np.asarray(choice[1], np.float64))
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

    def policy_scores(self, dataset) -> torch.Tensor:
        """policy_mix: (k, n) log prior + summed step log-likelihood of each of ``dataset``'s
        trajectories under each of the model's policies."""
        states, offsets = self._checked_states(dataset)
        if int(dataset.n_actions) != self.policy.n_actions:
            raise DataError(
                f"policy_mix model was fitted on {self.policy.n_actions} actions, "
                f"dataset {dataset.domain}-{dataset.env} has {dataset.n_actions}"
            )
        seen = policy_states(dataset, states, self.policy.time)
        with torch.no_grad():
            inputs = policy_inputs(dataset, seen, self.mean, self.std)
            return trajectory_scores(self.policy, inputs, len(offsets) - 1)

    def choice_scores(self, dataset) -> np.ndarray:
        """choice_mix: (n, k) log share + log-likelihood of each trajectory's moves."""
        from pcpg_dist.stages.clustering.choice_mix import choice_scores
        from pcpg_dist.stages.clustering.move_pairs import load_move_features, pairs_of

        self._checked_states(dataset)
        spec = self.move_features
        if spec is None:
            raise DataError("a choice_mix model needs its move-feature function (load_model)")
        pairs = pairs_of(dataset, load_move_features(spec), spec)
        if pairs.phi.shape[1] != len(self.mean):
            raise DataError(
                f"choice_mix model was fitted on {len(self.mean)} move features, {spec} "
                f"gives {pairs.phi.shape[1]}"
            )
        w, log_share = self.choice
        return choice_scores(
            pairs, w, log_share, self.mean.astype(np.float64), self.std.astype(np.float64)
        )

    def features(self, dataset) -> np.ndarray:
        """The space the centroids live in: latents (LSTM methods) or normalised summaries."""
        if self.choice is not None:
            from pcpg_dist.stages.clustering import choice_mix

            return choice_mix.posteriors(self.choice_scores(dataset))
        states, offsets = self._checked_states(dataset)
        if self.bag is not None:
            actions = np.asarray(dataset.actions, np.int64)
            return normalize(bag_matrix(states, offsets, actions, self.bag))
        if self.vocabulary is not None:
            return visit_features(states, offsets, self.vocabulary)
        if self.policy is not None:
            return posteriors(self.policy_scores(dataset))
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
        states, _ = self._checked_states(dataset)
        return float((state_columns(states, self.bag.states) < 0).mean())

    def _greedy_predict(self, dataset) -> np.ndarray:
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
        if self.choice is not None:
            tensors["choice_w"] = torch.from_numpy(self.choice[0])
            tensors["choice_log_share"] = torch.from_numpy(self.choice[1])
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
            meta["policy_time"] = self.policy.time
        if self.choice is not None:
            meta["move_width"] = int(self.choice[0].shape[1])
        (directory / CONFIG_FILE).write_text(json.dumps(meta, indent=2, sort_keys=True))
        return directory


@dataclass(frozen=True)
class Fitted:
    """What a clusterer's fitting function (a target of :data:`pcpg_dist.config.clusterers.CLUSTERERS`)
    returns to :func:`pcpg_dist.stages.clustering.cluster`."""

    labels: np.ndarray | None  # (n,) or None: the model's nearest centroid of each latent
    latents: np.ndarray  # the space the clusters live in (dense or sparse rows)
    model: ClusterModel
    margins: np.ndarray | None = None  # from the clusterers with a likelihood
    #: whether a silhouette of ``latents`` says how well the clusters separate. Not for
    #: posteriors of a likelihood summed over whole trajectories: they are near one-hot for any
    #: partition EM settles in, so their silhouette reads ~1 (0.99 on highway, where the
    #: clusters are 0.60 accurate and not stable)
    silhouette: bool = True
