"""The LSTM sequence autoencoder of Step A (``lstm_dec``, ``lstm_kmeans``) and its batching.

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

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.nn.utils.rnn import PackedSequence

from pcpg_dist.common.errors import DataError
from pcpg_dist.stages.clustering.policy_network import uniform_init


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
        uniform_init((self.to_latent, self.to_state), generator)

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
