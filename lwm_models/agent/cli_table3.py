"""`lwm agent table3`: the paper's Table 3 on N test games per split, with the shipped models."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..data.dataset import TrajectoryDataset
from ..errors import LwmError
from ..world.checkpoint import load_checkpoint
from ..world.frozen_text import FrozenTextEncoder
from ..world.shipped import SHIPPED, SHIPPED_POLICY
from .policy import EmmaPolicy
from .review import load_policy
from .table3 import Budget, run_game, summarize

PAPER = {  # real return, from the paper (shared/docs/messenger-wm.md §4)
    ("online_il", "observational"): (0.75, -0.41, -0.21),
    ("online_il", "emma"): (1.01, 0.96, 0.62),
    ("online_il", "oracle"): (1.04, 0.85, 0.91),
    ("filtered_bc", "observational"): (0.77, -0.42, -0.30),
    ("filtered_bc", "emma"): (1.18, 0.75, 0.44),
    ("filtered_bc", "oracle"): (1.17, 0.84, 0.80),
}
SPLITS = ("newcombo-test", "newattr-test", "newall-test")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", type=Path, required=True, help="dataset directory (test games and their manuals)")
    p.add_argument("--games", type=int, default=30, help="test games per split (the paper: 30)")
    p.add_argument("--splits", nargs="+", default=list(SPLITS))
    p.add_argument(
        "--models", nargs="+", default=None, help="KIND=CHECKPOINT pairs (default: the shipped emma and observational)"
    )
    p.add_argument(
        "--settings",
        nargs="+",
        default=["online_il", "filtered_bc"],
        choices=["online_il", "filtered_bc", "warm_start"],
    )
    p.add_argument("--policy", type=Path, default=None, help="warm-start policy (default: shipped, else untrained)")
    p.add_argument("--updates", type=int, default=20, help="policy updates per game")
    p.add_argument("--episodes", type=int, default=16, help="imagined episodes per update")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=None, help="write the results as JSON")
    p.add_argument("--no-progress", action="store_true")


def run_table3(args: argparse.Namespace) -> int:
    models = {}
    pairs = args.models or [f"{k}={v}" for k, v in SHIPPED.items()]
    for pair in pairs:
        if "=" not in pair:
            raise LwmError(f"--models takes KIND=CHECKPOINT pairs, got {pair!r}")
        name, path = pair.split("=", 1)
        models[name] = load_checkpoint(path)
    warm = (
        load_policy(args.policy or SHIPPED_POLICY)
        if (args.policy or (SHIPPED_POLICY / "config.json").is_file())
        else EmmaPolicy().eval()
    )
    encoder = FrozenTextEncoder()
    budget = Budget(updates=args.updates, episodes=args.episodes)
    results: dict = {"budget": budget.__dict__, "seed": args.seed, "games_per_split": args.games, "rows": {}}
    began = time.perf_counter()
    total = len(args.settings) * len(models) * len(args.splits) * args.games
    bar = tqdm(total=total, desc="table 3", disable=args.no_progress)
    for split in args.splits:
        ds = TrajectoryDataset(args.data, split)
        games = np.linspace(0, len(ds.games) - 1, min(args.games, len(ds.games))).round().astype(int)
        first_episode = {int(g): int(np.flatnonzero(np.asarray(ds.episode_games) == g)[0]) for g in games}
        for setting in args.settings:
            for name, (world, config) in models.items():
                per_game = []
                for g in games:
                    manual = ds[first_episode[int(g)]].manual
                    per_game.append(
                        run_game(
                            setting,
                            world,
                            config["kind"],
                            warm,
                            ds.games[g],
                            manual,
                            encoder,
                            budget,
                            args.seed + int(g),
                        )
                    )
                    bar.update(1)
                row = results["rows"].setdefault(f"{setting}/{name}", {})
                row[split] = {
                    **summarize([r["return"] for r in per_game]),
                    "learn_seconds_per_game": float(np.mean([r["learn_seconds"] for r in per_game])),
                }
    bar.close()
    results["cpu_seconds"] = round(time.perf_counter() - began, 1)
    print(f"Table 3: mean real return over {args.games} games per split (95% interval); paper in brackets")
    print(f"{'setting / model':<28}" + "".join(f"{s:>26}" for s in args.splits))
    for key, row in results["rows"].items():
        setting, name = key.split("/")
        paper = PAPER.get((setting, name))
        cells = []
        for s in args.splits:
            r = row[s]
            ref = f" [{paper[SPLITS.index(s)]:+.2f}]" if paper and s in SPLITS else ""
            cells.append(f"{r['mean']:+.2f} ({r['ci95'][0]:+.2f},{r['ci95'][1]:+.2f}){ref}")
        print(f"{key:<28}" + "".join(f"{c:>26}" for c in cells))
    print(f"CPU time: {results['cpu_seconds']:.0f} s")
    if args.out:
        args.out.write_text(json.dumps(results, indent=2))
    return 0
