"""EMMA policy training step, in one run, same weights and states: the dense reference (paint the
grid and convolve it, `forward_dense`) at the baseline minibatch, against the sparse first
convolution (`forward`, what the agent trains with) at each minibatch asked for. The learning
budgets take one step per minibatch, so ms per step is what a round of learning waits for; labels
per second is the throughput.

    .venv/bin/python benchmarks/policy_speed.py [--batches 256 64] [--steps 20] [--threads 1]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
import torch.nn.functional as F

from lwm_models.agent.policy import EmmaPolicy, stack_history
from lwm_models.data.splits import load_split
from lwm_models.messenger import rollout
from lwm_models.world.base import ManualBatch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--batches", type=int, nargs="+", default=[256, 64], help="minibatches; the first is the baseline's"
    )
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    most = max(args.batches)
    games = load_split("train")[:most]
    ro = rollout(games, np.arange(len(games)), np.zeros(len(games), dtype=np.int64))  # random actions
    rng = np.random.default_rng(0)
    history = np.stack(
        [stack_history(ro.observations[i : i + 1, : rng.integers(1, ro.lengths[i] + 1)])[0] for i in range(len(games))]
    )
    h = torch.from_numpy(history)
    labels = torch.from_numpy(rng.integers(0, 5, len(h)))
    manual = ManualBatch(torch.randn(1, 3, 36, 384), torch.ones(1, 3, 36, dtype=torch.bool))
    policy = EmmaPolicy()
    opt = torch.optim.Adam(policy.parameters(), lr=1e-3)
    runs = [("forward_dense", args.batches[0])] + [("forward", b) for b in args.batches]
    results: dict[tuple[str, int], list[float]] = {}
    for name, batch in runs + runs:  # twice, alternating
        fn = getattr(policy, name)
        began = time.perf_counter()
        for _ in range(args.steps):
            loss = F.cross_entropy(fn(h[:batch], policy.id_values(manual).expand(batch, -1, -1)), labels[:batch])
            opt.zero_grad()
            loss.backward()
            opt.step()
        results.setdefault((name, batch), []).append((time.perf_counter() - began) / args.steps * 1000)
    base = min(results[runs[0]])
    print(f"{args.threads} thread(s), best of 2 x {args.steps} steps")
    print(f"baseline: dense grid + convolution, minibatch {args.batches[0]}: {base:7.1f} ms/step")
    for name, batch in runs[1:]:
        ms = min(results[(name, batch)])
        print(
            f"sparse first convolution, minibatch {batch:4d}: {ms:7.1f} ms/step ({base / ms:.1f}x the baseline's "
            f"steps/s), {batch / ms * 1000:8.0f} labels/s"
        )


if __name__ == "__main__":
    main()
