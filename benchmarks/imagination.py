"""Imagination speed: seconds per batch of 32-step trajectories at batch 1, 16 and 64, on each
decoding path (world/decoding.py) measured in the same run, with the ratio to the reference path
and the arithmetic floor beside each. Target: 64 imagined 32-step trajectories in <= 1 s on 2 cores.

    .venv/bin/python benchmarks/imagination.py [--checkpoint DIR] [--repeats 3] [--json PATH] [--no-cache]

Trajectories are forced to the full 32 steps (stop_on_done=False), the worst case: a trajectory
that the model ends early is cheaper. The paths take turns within each repeat (machines are
noisy: compare ratios, not absolute times across runs), and the best of the repeats is reported.
"stepwise" is the speculative path given the actions a step at a time (a policy's imagination, a
server's session): every row waits for the others at each step's end.

The floor is the decoder's arithmetic, counted from the model's config (`trajectory_flops`), at the
sgemm rate this machine reaches in this run (a 1024^3 float32 matmul on torch's threads).
--no-cache adds the no-KV-cache comparison (minutes at batch 64, so on a shorter horizon there).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import time
from datetime import date
from pathlib import Path

import numpy as np
import torch

from lwm_models.data.splits import load_split
from lwm_models.messenger.engine import BatchedMessenger
from lwm_models.text import DescriptionPools
from lwm_models.world.checkpoint import load_checkpoint
from lwm_models.world.gpt import DecoderConfig
from lwm_models.world.imagine import StepwiseImagination, imagine
from lwm_models.world.lanes import lanes
from lwm_models.world.shipped import shipped_checkpoint
from lwm_models.world.tokens import BLOCK, DONE_VOCAB, OBS_TOKENS, OBS_VOCAB, REWARD_VOCAB

TARGET_S = 1.0
STEPS = 32
BATCHES = (1, 16, 64)
PATHS = ("reference", "flat", "speculative", "stepwise")
# "stepwise": the speculative path a step at a time, every row waiting for the others at each step's
# end, as imagination acted by a policy (the agent) or a server's sessions runs; `imagine` with known
# actions takes every step in the scripted graph (StepwiseImagination.run).


def trajectory_flops(cfg: DecoderConfig, steps: int = STEPS) -> float:
    """Multiply-adds x 2 of one trajectory: every token fed through every layer (projections, MLP,
    attention over the tokens before it) and the output head of every sampled token. The first
    block feeds 14 tokens, each step 15 (the pending done, the action, 13 sampled ones)."""
    h, d, kvh = cfg.hidden, cfg.hidden // cfg.heads, cfg.num_kv_heads
    per_token = 2 * h * (h + 2 * kvh * d) + 2 * h * h + 2 * 2 * h * 4 * h  # qkv, proj, MLP
    tokens = (BLOCK - 1) + steps * BLOCK
    attention = 2 * 2 * cfg.heads * d * sum(p + 1 for p in range(tokens))  # scores and values
    heads = steps * sum(
        k * 2 * (h * h + h * v) for k, v in ((OBS_TOKENS, OBS_VOCAB), (1, REWARD_VOCAB), (1, DONE_VOCAB))
    )
    return cfg.layers * (tokens * per_token + attention) + heads


def sgemm_rate(size: int = 1024, repeats: int = 5) -> float:
    """FLOP/s of a float32 matmul on torch's threads, best of `repeats`."""
    a, b = torch.randn(size, size), torch.randn(size, size)
    a @ b
    best = float("inf")
    for _ in range(repeats):
        began = time.perf_counter()
        a @ b
        best = min(best, time.perf_counter() - began)
    return 2 * size**3 / best


def git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    except OSError:
        return "unknown"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", default=None, help="checkpoint directory (default: shipped EMMA-LWM)")
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats per path; the best is reported")
    parser.add_argument("--json", default=None, help="also write the figures to this file")
    parser.add_argument("--no-cache", action="store_true", help="add the no-KV-cache comparison (slow)")
    parser.add_argument("--no-cache-steps", type=int, default=8, help="horizon of the batch-64 no-cache comparison")
    parser.add_argument(
        "--threads", type=int, default=None, help="torch intra-op threads (default: torch's; the system's nodes use 1)"
    )
    parser.add_argument("--batches", type=int, nargs="+", default=list(BATCHES), help="trajectories per batch")
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)

    path = args.checkpoint or shipped_checkpoint("emma")
    model, config = load_checkpoint(path)
    game = load_split("newall-test")[0]
    engine = BatchedMessenger()
    engine.reset([game], [0])
    first = engine.compact_observation()[0]
    manual = DescriptionPools.generated().draw("newall-test", list(game.triples), np.random.default_rng(0))
    batch = model.read_manual(manual, model.frozen_text_encoder(), list(game.triples))
    flops = trajectory_flops(model.decoder_config)
    available = lanes()
    lane_count = available.count if available is not None else 1  # threads a speculative step's rows are cut over
    rate = sgemm_rate()
    print(
        f"model: {config['kind']} {config['config']['decoder']} ({config['parameters']:,} parameters), "
        f"torch threads {torch.get_num_threads()}, lanes {lane_count}\n"
        f"arithmetic: {flops / 1e9:.3f} GFLOP per {STEPS}-step trajectory; sgemm here {rate / 1e9:.0f} GFLOP/s"
    )

    def run(n: int, decoding: str, steps: int = STEPS, cache: bool = True) -> None:
        actions = np.random.default_rng(0).integers(5, size=(n, steps))
        if decoding == "stepwise":
            stepwise(n, actions)
            return
        imagine(
            model,
            batch,
            first,
            n=n,
            actions=actions,
            max_steps=steps,
            seed=0,
            use_cache=cache,
            stop_on_done=False,
            decoding=decoding,
        )

    def rollout(n: int) -> StepwiseImagination:
        return StepwiseImagination(
            model, batch, first, n=n, max_steps=STEPS, seed=0, stop_on_done=False, decoding="speculative"
        )

    def stepwise(n: int, actions: np.ndarray) -> StepwiseImagination:
        stepped = rollout(n)
        for t in range(STEPS):
            stepped.step(actions[:, t])
        return stepped

    def calls_per_step(n: int) -> tuple[float, float]:
        """Decoder calls per step on the speculative path: a whole run of the actions, a step at a time."""
        actions = np.random.default_rng(0).integers(5, size=(n, STEPS))
        whole = rollout(n)
        whole.run(actions)
        return whole._rows.calls / STEPS, stepwise(n, actions)._rows.calls / STEPS

    rows = []
    print(
        f"\n{'batch':>5} | "
        + " | ".join(f"{p:>11}" for p in PATHS)
        + " | speculative vs reference | stepwise vs reference | floor | over floor"
    )
    for n in args.batches:
        best = dict.fromkeys(PATHS, float("inf"))
        for p in PATHS:
            run(n, p)  # warm-up (and the scripted graphs' first runs)
        for _ in range(args.repeats):
            for p in PATHS:  # in turns, so that a noisy moment hits every path alike
                began = time.perf_counter()
                run(n, p)
                best[p] = min(best[p], time.perf_counter() - began)
        floor = n * flops / rate
        ratio = best["reference"] / best["speculative"]
        calls, stepwise_calls = calls_per_step(n)
        rows.append(
            {
                "batch": n,
                "steps": STEPS,
                "seconds": {p: round(best[p], 4) for p in PATHS},
                "ratio_to_reference": {p: round(best["reference"] / best[p], 2) for p in PATHS},
                "floor_seconds": round(floor, 4),
                "speculative_over_floor": round(best["speculative"] / floor, 1),
                "reference_over_floor": round(best["reference"] / floor, 1),
                "speculative_calls_per_step": round(calls, 2),
                "stepwise_calls_per_step": round(stepwise_calls, 2),
            }
        )
        print(
            f"{n:>5} | "
            + " | ".join(f"{best[p]:9.3f} s" for p in PATHS)
            + f" | {ratio:5.2f}x (flat {best['reference'] / best['flat']:.2f}x)"
            + f" | {best['reference'] / best['stepwise']:5.2f}x"
            + f" | {floor:.4f} s | {best['speculative'] / floor:.0f}x (reference {best['reference'] / floor:.0f}x)"
        )
    print(
        "speculative decoder calls per step (stepwise): "
        + ", ".join(
            f"batch {r['batch']} {r['speculative_calls_per_step']} ({r['stepwise_calls_per_step']})" for r in rows
        )
    )

    for row in rows:
        if row["batch"] == 64:
            t64 = row["seconds"]["speculative"]
            print(
                f"target: 64 x 32-step trajectories in <= {TARGET_S:.1f} s: {'met' if t64 <= TARGET_S else 'MISSED'} "
                f"({t64:.2f} s, default path)"
            )

    if args.no_cache:
        for n in (1, 64):
            steps = STEPS if n == 1 else args.no_cache_steps
            began = time.perf_counter()
            run(n, "reference", steps, cache=False)
            slow = time.perf_counter() - began
            began = time.perf_counter()
            run(n, "reference", steps)
            fast = time.perf_counter() - began
            print(
                f"batch {n:>2}, {steps:>2} steps, no cache vs cache: {slow:7.2f} s vs {fast:.2f} s ({slow / fast:.0f}x)"
            )

    if args.json:
        out = {
            "benchmark": "imagination",
            "command": "benchmarks/imagination.py"
            + (f" --checkpoint {args.checkpoint}" if args.checkpoint else "")
            + (f" --threads {args.threads}" if args.threads is not None else "")
            + (f" --batches {' '.join(map(str, args.batches))}" if args.batches != list(BATCHES) else ""),
            "date": date.today().isoformat(),
            "commit": git_commit(),
            "checkpoint": str(path),
            "torch": torch.__version__,
            "threads": torch.get_num_threads(),
            "lanes": lane_count,
            "repeats": args.repeats,
            "gflop_per_trajectory": round(flops / 1e9, 4),
            "sgemm_gflops": round(rate / 1e9, 1),
            "rows": rows,
        }
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
