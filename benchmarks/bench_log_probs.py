"""policy_mix's per-step log-likelihood, side by side: masked_fill + log_softmax + gather (as
until the eighth session) against :func:`pcpg_dist.stages.clustering.policy_network.
picked_log_probs` (picked - max - log sum exp over an additive mask), forward and backward, one
torch thread, on the shapes policy_mix fits (32,768 rows, k = 4 heads, 64 hidden units).

    uv run python -m benchmarks.bench_log_probs [--rows 32768] [--repeats 30]

Prints milliseconds per forward + backward and the ratio old / new for each action count; then,
with every action valid (most logs), the additive mask added anyway (as until the eighteenth
session) against ``picked_log_probs``, which skips an all-zero mask; then, with a few legal ids
of many (othello's 65 ids, about 10 legal), exp taken of the masked -1e9 entries too (as until
the thirtieth session) against ``picked_log_probs``'s :func:`masked_exp`.
"""

from __future__ import annotations

import argparse
import time

import torch

from pcpg_dist.stages.clustering.policy_network import picked_log_probs


def old_log_probs(logits: torch.Tensor, actions: torch.Tensor, valid: torch.Tensor):
    """The previous PolicyMixture.step_log_probs tail, (k, rows)."""
    k = logits.shape[1]
    logits = logits.permute(1, 0, 2).masked_fill(~valid, -1e9)
    return torch.log_softmax(logits, -1).gather(2, actions.expand(k, -1).unsqueeze(-1)).squeeze(-1)


def new_log_probs(logits: torch.Tensor, actions: torch.Tensor, valid: torch.Tensor):
    return picked_log_probs(logits, actions, valid).T


def masked_anyway(logits: torch.Tensor, actions: torch.Tensor, valid: torch.Tensor):
    """picked_log_probs as until the eighteenth session: the mask added even when all-zero."""
    mask = torch.zeros(valid.shape).masked_fill_(~valid, -1e9)
    return new_log_probs(logits + mask.view(len(actions), 1, -1), actions, valid)


def unfloored(logits: torch.Tensor, actions: torch.Tensor, valid: torch.Tensor):
    """picked_log_probs as until the thirtieth session: exp of every entry, the masked too."""
    mask = torch.zeros(valid.shape).masked_fill_(~valid, -1e9)
    logits = logits + mask.view(len(actions), 1, -1)
    top = logits.detach().amax(-1, keepdim=True)
    picked = logits.gather(-1, actions.view(-1, 1, 1).expand(*logits.shape[:-1], 1))
    return (picked - top - (logits - top).exp().sum(-1, keepdim=True).log()).squeeze(-1).T


def drawn(gen: torch.Generator, rows: int, hidden: int, k: int, n_actions: int, scale: float = 1.0):
    """A problem's features, heads' weight (``scale`` x N(0, 1), trained) and taken actions."""
    features = torch.randn(rows, hidden, generator=gen)
    weight = (scale * torch.randn(hidden, k * n_actions, generator=gen)).requires_grad_()
    return features, weight, torch.randint(n_actions, (rows,), generator=gen)


def timed(fn, features, weight, actions, valid, k: int, n_actions: int, repeats: int) -> float:
    """Milliseconds per forward + backward of ``fn`` after the heads' matrix product."""
    for step in range(repeats + 3):  # 3 warm-up calls
        if step == 3:
            start = time.perf_counter()
        logits = (features @ weight).view(len(features), k, n_actions)
        fn(logits, actions, valid).mean().backward()
    return (time.perf_counter() - start) / repeats * 1000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=32768)
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args()
    torch.set_num_threads(1)
    gen = torch.Generator().manual_seed(0)
    k, hidden = 4, 64
    print(f"{'actions':>7} {'old ms':>8} {'new ms':>8} {'old/new':>8}")
    for n_actions in (3, 5, 9, 18):
        features, weight, actions = drawn(gen, args.rows, hidden, k, n_actions)
        valid = torch.rand(args.rows, n_actions, generator=gen) > 0.2
        valid[torch.arange(args.rows), actions] = True
        logits = (features @ weight).view(args.rows, k, n_actions)
        same = torch.allclose(
            old_log_probs(logits, actions, valid), new_log_probs(logits, actions, valid), atol=1e-4
        )
        if not same:
            raise SystemExit(f"{n_actions} actions: the two computations disagree")
        old, new = (
            timed(fn, features, weight, actions, valid, k, n_actions, args.repeats)
            for fn in (old_log_probs, new_log_probs)
        )
        print(f"{n_actions:>7} {old:>8.2f} {new:>8.2f} {old / new:>8.2f}")
    print(f"\nevery action valid\n{'actions':>7} {'masked':>8} {'skipped':>8} {'ratio':>8}")
    for n_actions in (3, 6, 18):
        features, weight, actions = drawn(gen, args.rows, hidden, k, n_actions)
        valid = torch.ones(args.rows, n_actions, dtype=torch.bool)
        anyway, skipped = (
            timed(fn, features, weight, actions, valid, k, n_actions, args.repeats)
            for fn in (masked_anyway, new_log_probs)
        )
        print(f"{n_actions:>7} {anyway:>8.2f} {skipped:>8.2f} {anyway / skipped:>8.2f}")
    print(
        f"\na few legal of many\n{'actions':>7} {'legal':>6} {'exp all':>8} {'floored':>8} {'ratio':>8}"
    )
    for n_actions, legal in ((65, 0.15), (65, 0.5), (18, 0.5)):
        features, weight, actions = drawn(gen, args.rows, hidden, k, n_actions, 0.3)
        valid = torch.rand(args.rows, n_actions, generator=gen) < legal
        valid[torch.arange(args.rows), actions] = True
        logits = (features @ weight).view(args.rows, k, n_actions)
        if not torch.equal(
            unfloored(logits, actions, valid), new_log_probs(logits, actions, valid)
        ):
            raise SystemExit(f"{n_actions} actions, {legal:.0%} legal: the two disagree")
        every, floored = (
            timed(fn, features, weight, actions, valid, k, n_actions, args.repeats)
            for fn in (unfloored, new_log_probs)
        )
        print(f"{n_actions:>7} {legal:>6.0%} {every:>8.2f} {floored:>8.2f} {every / floored:>8.2f}")


if __name__ == "__main__":
    main()
