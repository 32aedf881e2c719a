"""The most continuous batching can give here: the load benchmark's calls, in process, without ROS.

    .venv/bin/python benchmarks/batch_bound.py [--clients 8] [--calls 800] [--repeats 3] [--checkpoint DIR]

`ros_stress.py load` asks that 8 clients get >= 5x the calls per second of one. This runs the
same calls (`ros_stress.imagine_request`, under the environment node's first manual) through the
world-model server's `ContinuousBatch` as closed loops: N clients, each starting its next call the moment
its last one ends, against one client doing the same. No ROS, no pipes, no JSON, no round trips:
what is left is the model's steps and the batch's own work (admitting calls, rows joining and
leaving the KV cache), on one core as in the world-model server's worker process. Whatever ratio this
prints is an upper bound for the real system's, apart from the per-call costs of the one client
that batching hides (which is why the real system can exceed it a little).

The runs alternate (1, N, 1, N, ...) so that a drift of the machine's speed hits both; each
repeat prints its ratio, and the median is the figure.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ros_stress import imagine_request  # noqa: E402  (the load benchmark's requests)

from lwm_models.data.session import GameSession  # noqa: E402
from lwm_models.world.continuous import ContinuousBatch  # noqa: E402
from lwm_models.world.model_server import WorldModelServer  # noqa: E402


def closed_loop(sim: WorldModelServer, clients: int, calls: int) -> dict:
    """`clients` calls in flight until `calls` have ended; calls/s, steps/s and ms per batch step."""
    batch = ContinuousBatch(sim.model)
    numbers = iter(range(10**9))
    for _ in range(clients):
        batch.admit(sim.one_shot(imagine_request(next(numbers))))
    ended = 0
    stepping = 0.0
    began = time.perf_counter()
    while ended < calls:
        t = time.perf_counter()
        done = batch.step()
        stepping += time.perf_counter() - t
        for shot in done:
            shot.result()
            batch.admit(sim.one_shot(imagine_request(next(numbers))))
        ended += len(done)
    wall = time.perf_counter() - began
    return {
        "calls/s": ended / wall,
        "steps/s": batch.row_steps / wall,
        "width": batch.row_steps / batch.steps,
        "step ms": stepping / batch.steps * 1e3,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clients", type=int, default=8, help="calls in flight in the batched run")
    parser.add_argument("--calls", type=int, default=800, help="calls per batched run (one client makes 1/5 of it)")
    parser.add_argument("--repeats", type=int, default=3, help="alternating pairs of runs")
    parser.add_argument("--checkpoint", default=None, help="checkpoint directory (default: shipped EMMA-LWM)")
    args = parser.parse_args()
    if args.clients < 1 or args.calls < 1 or args.repeats < 1:
        parser.error("--clients, --calls and --repeats must be >= 1")
    torch.set_num_threads(1)  # the world-model server's worker process runs one thread
    sim = WorldModelServer(args.checkpoint)
    game = GameSession("newall-test", 0, None, 32)  # what the environment node starts with
    game.reset(0)
    sim.set_manual(game.manual()["descriptions"])
    closed_loop(sim, 1, 20)  # warm-up
    ratios = []
    for r in range(args.repeats):
        one = closed_loop(sim, 1, max(1, args.calls // 5))
        many = closed_loop(sim, args.clients, args.calls)
        ratios.append(many["calls/s"] / one["calls/s"])
        print(
            f"repeat {r + 1}: one client {one['calls/s']:.1f} calls/s ({one['step ms']:.2f} ms per step); "
            f"{args.clients} clients {many['calls/s']:.1f} calls/s ({many['step ms']:.2f} ms per step of "
            f"{many['width']:.2f} rows); ratio {ratios[-1]:.2f}x",
            flush=True,
        )
    print(f"median ratio {statistics.median(ratios):.2f}x over {args.repeats} pairs (load target: >= 5x)")


if __name__ == "__main__":
    main()
