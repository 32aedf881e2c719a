"""Imagination speed: trajectories/s at batch 1 and 64 with the KV cache, beside the same model
without it, in one run. Target: 64 imagined 32-step trajectories in <= 1 s on 2 cores.

    .venv/bin/python benchmarks/imagination.py [--checkpoint DIR] [--repeats 3]

Trajectories are forced to the full 32 steps (stop_on_done=False), the worst case: a trajectory
that the model ends early is cheaper. At batch 64 the no-cache path is compared on a shorter
horizon (--no-cache-steps), as a full run of it takes minutes.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from lwm_models.data.splits import load_split
from lwm_models.messenger.engine import BatchedMessenger
from lwm_models.text import DescriptionPools
from lwm_models.world.checkpoint import load_checkpoint
from lwm_models.world.imagine import imagine
from lwm_models.world.shipped import shipped_checkpoint

TARGET_S = 1.0


def timed(fn, repeats: int) -> float:
    fn()  # warm-up
    best = float("inf")
    for _ in range(repeats):
        began = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - began)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", default=None, help="checkpoint directory (default: shipped EMMA-LWM)")
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats; the best is reported")
    parser.add_argument("--no-cache-steps", type=int, default=8, help="horizon of the batch-64 no-cache comparison")
    args = parser.parse_args()

    path = args.checkpoint or shipped_checkpoint("emma")
    model, config = load_checkpoint(path)
    game = load_split("newall-test")[0]
    engine = BatchedMessenger()
    engine.reset([game], [0])
    first = engine.compact_observation()[0]
    manual = DescriptionPools.generated().draw("newall-test", list(game.triples), np.random.default_rng(0))
    encoder = model.frozen_text_encoder()
    batch = model.read_manual(manual, encoder, list(game.triples))
    print(
        f"model: {config['kind']} {config['config']['decoder']} ({config['parameters']:,} parameters), "
        f"torch threads {torch.get_num_threads()}"
    )

    def run(n: int, steps: int = 32, cache: bool = True) -> None:
        actions = np.random.default_rng(0).integers(5, size=(n, steps))
        imagine(model, batch, first, n=n, actions=actions, max_steps=steps, seed=0, use_cache=cache, stop_on_done=False)

    results = {}
    for n in (1, 64):
        full = timed(lambda n=n: run(n), args.repeats)
        results[n] = full
        print(f"batch {n:>2}, 32 steps, KV cache   : {full:7.2f} s  ({n / full:7.1f} trajectories/s)")
        # Without the cache every token recomputes the whole prefix; at batch 64 a full run takes
        # minutes, so both paths are compared on the same shorter horizon there.
        steps = 32 if n == 1 else args.no_cache_steps
        slow = timed(lambda n=n, steps=steps: run(n, steps, cache=False), 1)
        fast = full if steps == 32 else timed(lambda n=n, steps=steps: run(n, steps), args.repeats)
        print(
            f"batch {n:>2}, {steps:>2} steps, no cache vs cache: {slow:7.2f} s vs {fast:.2f} s "
            f"(the cache is {slow / fast:.0f}x faster)"
        )
    t64 = results[64]
    print(
        f"target: 64 x 32-step trajectories in <= {TARGET_S:.1f} s: {'met' if t64 <= TARGET_S else 'MISSED'} "
        f"({t64:.2f} s)"
    )


if __name__ == "__main__":
    main()
