"""EMMA policy training step, in one run, same weights and states: the dense reference (paint the
grid and convolve it, `forward_dense`) at the baseline minibatch, against the sparse first
convolution (`forward`, what the agent trains with) at each minibatch asked for. The learning
budgets take one step per minibatch, so ms per step is what a round of learning waits for; labels
per second is the throughput. The floor beside each is the step's arithmetic (forward, backward and
Adam, counted by torch's FLOP counter) at the float32 matmul rate this run reaches on its threads.

    .venv/bin/python benchmarks/policy_speed.py [--batches 256 64] [--steps 20] [--threads 1] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import time
from datetime import date
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from imagination import git_commit, sgemm_rate  # benchmarks/ is on sys.path when run as a script

from lwm_models.agent.policy import EmmaPolicy, stack_history
from lwm_models.data.splits import load_split
from lwm_models.messenger import rollout
from lwm_models.world.base import ManualBatch


def step_flops(fn, h: torch.Tensor, ids: torch.Tensor, labels: torch.Tensor) -> int:
    """FLOPs of one training step's forward and backward (torch.utils.flop_counter; Adam's
    elementwise update is not counted: ~1M parameters, under 1% of the rest)."""
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter:
        F.cross_entropy(fn(h, ids), labels).backward()
    return counter.get_total_flops()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--batches", type=int, nargs="+", default=[256, 64], help="minibatches; the first is the baseline's"
    )
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", default=None, help="also write the figures to this file")
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
    rate = sgemm_rate()
    floors = {}
    for name, batch in runs:
        policy.zero_grad()
        flops = step_flops(
            getattr(policy, name), h[:batch], policy.id_values(manual).expand(batch, -1, -1), labels[:batch]
        )
        floors[(name, batch)] = flops / rate * 1000
    base = min(results[runs[0]])
    print(f"{args.threads} thread(s), best of 2 x {args.steps} steps; sgemm here {rate / 1e9:.0f} GFLOP/s")
    print(
        f"baseline: dense grid + convolution, minibatch {args.batches[0]}: {base:7.1f} ms/step "
        f"(floor {floors[runs[0]]:.2f} ms, {base / floors[runs[0]]:.0f}x it)"
    )
    rows = [{"step": "dense", "batch": args.batches[0], "ms": round(base, 2), "ratio": 1.0,
             "floor_ms": round(floors[runs[0]], 3)}]  # fmt: skip
    for name, batch in runs[1:]:
        ms = min(results[(name, batch)])
        floor = floors[(name, batch)]
        print(
            f"sparse first convolution, minibatch {batch:4d}: {ms:7.1f} ms/step ({base / ms:.1f}x the baseline's "
            f"steps/s), {batch / ms * 1000:8.0f} labels/s; floor {floor:.2f} ms ({ms / floor:.0f}x it)"
        )
        rows.append({"step": "sparse", "batch": batch, "ms": round(ms, 2), "ratio": round(base / ms, 2),
                     "floor_ms": round(floor, 3)})  # fmt: skip
    if args.json:
        out = {
            "benchmark": "policy_speed",
            "command": "benchmarks/policy_speed.py --batches " + " ".join(map(str, args.batches))
            + f" --steps {args.steps} --threads {args.threads}",
            "date": date.today().isoformat(),
            "commit": git_commit(),
            "torch": torch.__version__,
            "threads": args.threads,
            "sgemm_gflops": round(rate / 1e9, 1),
            "rows": rows,
        }  # fmt: skip
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
