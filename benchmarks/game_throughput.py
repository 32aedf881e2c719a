"""Game speed: single-game steps/s, batched steps/s (N = 1, 64, 4096) and the time to generate the
full Messenger-WM benchmark, in one run. Targets (2-core CPU): >= 1,000,000 batched steps/s and the
full benchmark in <= 180 s.

    .venv/bin/python benchmarks/game_throughput.py [--skip-generate] [--out DIR]

A batched step counts every game in the batch that was still running (finished games are frozen
and not counted), so the figure is honest for policies that end episodes early.
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time

import numpy as np

from lwm_models.data.dataset import generate_dataset
from lwm_models.data.splits import load_split
from lwm_models.messenger import BatchedMessenger, MessengerEnv
from lwm_models.text import DescriptionPools

STEPS_TARGET = 1_000_000
GENERATE_TARGET_S = 180.0


def single_game_rate(seconds: float = 2.0) -> float:
    games = load_split("train")
    env = MessengerEnv(games[0])
    rng = np.random.default_rng(0)
    steps, episode = 0, 0
    env.reset(seed=episode)
    began = time.perf_counter()
    while time.perf_counter() - began < seconds:
        for a in rng.integers(5, size=256):
            env.step(int(a))
            steps += 1
            if env.done:
                episode += 1
                env = MessengerEnv(games[episode % len(games)], pools=env.pools)
                env.reset(seed=episode)
    return steps / (time.perf_counter() - began)


def batched_rate(n: int, seconds: float = 2.0) -> float:
    games = load_split("train")
    specs = [games[i % len(games)] for i in range(n)]
    engine = BatchedMessenger()
    rng = np.random.default_rng(0)
    live_steps, episode_seed = 0, 0
    began = time.perf_counter()
    while time.perf_counter() - began < seconds:
        engine.reset(specs, np.arange(n) + episode_seed)
        episode_seed += n
        # "stay" keeps most games alive for all 32 steps, so the batch stays full.
        actions = np.where(rng.random((32, n)) < 0.8, 4, rng.integers(4, size=(32, n)))
        for t in range(32):
            _, _, _, running = engine.step(actions[t])
            live_steps += int(running.sum())
    return live_steps / (time.perf_counter() - began)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--skip-generate", action="store_true", help="skip the full-benchmark generation")
    parser.add_argument("--out", default=None, help="keep the generated dataset here (default: a temp dir)")
    args = parser.parse_args()

    print(f"single game      : {single_game_rate():>12,.0f} steps/s")
    rates = {n: batched_rate(n) for n in (1, 64, 4096)}
    for n, rate in rates.items():
        print(f"batched N={n:<6}: {rate:>12,.0f} steps/s")
    best = rates[4096]
    print(
        f"target >= {STEPS_TARGET:,} batched steps/s: {'met' if best >= STEPS_TARGET else 'MISSED'} "
        f"({best / STEPS_TARGET:.2f}x)"
    )
    if args.skip_generate:
        return
    pools = DescriptionPools.generated()
    with tempfile.TemporaryDirectory() as tmp:
        began = time.perf_counter()
        index = generate_dataset(args.out or tmp, pools)
        seconds = time.perf_counter() - began
    episodes = sum(s["episodes"] for s in index["splits"].values())
    observations = sum(s["observations"] for s in index["splits"].values())
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        f"full benchmark   : {episodes:,} episodes, {observations:,} observations in {seconds:.1f} s "
        f"({episodes / seconds:,.0f} episodes/s); peak RSS {peak_mib:,.0f} MiB"
    )
    print(
        f"target <= {GENERATE_TARGET_S:.0f} s: {'met' if seconds <= GENERATE_TARGET_S else 'MISSED'} "
        f"({seconds / GENERATE_TARGET_S:.2f} of the budget)"
    )


if __name__ == "__main__":
    main()
