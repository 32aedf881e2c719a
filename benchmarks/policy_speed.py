"""EMMA policy training step: the sparse first convolution (what `forward` does) against painting
the grid and convolving it (`forward_dense`), in one run, same weights and batch.

    .venv/bin/python benchmarks/policy_speed.py [--batch 256] [--steps 20] [--threads 1]
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
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    games = load_split("train")[: args.batch]
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
    results = {}
    for name in ("forward_dense", "forward", "forward_dense", "forward"):  # twice, alternating
        fn = getattr(policy, name)
        began = time.perf_counter()
        for _ in range(args.steps):
            loss = F.cross_entropy(fn(h, policy.id_values(manual).expand(len(h), -1, -1)), labels)
            opt.zero_grad()
            loss.backward()
            opt.step()
        results.setdefault(name, []).append((time.perf_counter() - began) / args.steps * 1000)
    dense, sparse = min(results["forward_dense"]), min(results["forward"])
    print(f"batch {len(h)}, {args.threads} thread(s), best of 2 x {args.steps} steps")
    print(f"dense grid + convolution : {dense:7.1f} ms/step")
    print(f"sparse first convolution : {sparse:7.1f} ms/step ({dense / sparse:.1f}x faster)")


if __name__ == "__main__":
    main()
