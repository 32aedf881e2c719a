"""`lwm data splits|generate`: the Messenger-WM benchmark's game splits and trajectory dataset."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..messenger.constants import DEFAULT_MAX_STEPS, SPLITS
from .args import fraction, nonnegative_int, positive_int


def register(subparsers: argparse._SubParsersAction) -> None:
    data = subparsers.add_parser("data", help="the Messenger-WM benchmark: game splits and trajectories")
    data_sub = data.add_subparsers(dest="data_command", required=True)

    p = data_sub.add_parser("splits", help="generate the game splits and print their counts")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seed of the split generator")
    p.add_argument("--out", type=Path, default=None, help="also write the splits to this JSON file")
    p.set_defaults(func=run_splits)

    p = data_sub.add_parser("generate", help="generate the trajectory dataset")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument(
        "--text-source",
        nargs="+",
        default=["generated"],
        metavar="SOURCE",
        help="'generated' (the project's own descriptions) or human-written description JSON file(s)",
    )
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seed of episodes, policies and manuals")
    p.add_argument("--split-seed", type=nonnegative_int, default=0, help="seed of the game splits")
    p.add_argument("--episodes-per-game", type=positive_int, default=66, help="training episodes per training game")
    p.add_argument(
        "--max-games", type=positive_int, default=None, help="keep only the first N games of each split (default: all)"
    )
    p.add_argument("--max-steps", type=positive_int, default=DEFAULT_MAX_STEPS, help="time limit in actions")
    p.add_argument(
        "--splits",
        nargs="+",
        choices=SPLITS,
        default=list(SPLITS),
        metavar="SPLIT",
        help="generate only these splits (each split is seeded on its own, so its episodes do not change)",
    )
    p.add_argument("--typo-rate", type=fraction, default=0.0, help="typo rate of generated descriptions")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_generate)


def run_splits(args: argparse.Namespace) -> int:
    from ..data.splits import SPLIT_SIZES, make_splits

    splits = make_splits(args.seed)
    counts = splits.counts()
    width = max(map(len, counts))
    print(f"game splits (seed {args.seed})")
    for name, n in counts.items():
        mark = "ok" if n == SPLIT_SIZES[name] else f"expected {SPLIT_SIZES[name]}"
        print(f"  {name:<{width}}  {n:>5}  {mark}")
    if args.out:
        splits.save(args.out)
        print(f"written to {args.out}")
    return 0


def load_pools(text_source: list[str], seed: int, typo_rate: float = 0.0):
    """Description pools from 'generated' or from human-written description files."""
    from ..text import DescriptionPools

    if text_source == ["generated"]:
        return DescriptionPools.generated(seed=seed, typo_rate=typo_rate), "generated"
    return DescriptionPools.from_files(text_source, seed=seed), ",".join(text_source)


def run_generate(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from ..data.dataset import generate_dataset

    pools, source = load_pools(args.text_source, args.seed, args.typo_rate)
    if getattr(pools, "fallback_count", 0):
        print(
            f"note: {pools.fallback_count} (split, triple) pools had no human-written description "
            "and use generated ones",
            file=sys.stderr,
        )
    bar: tqdm | None = None

    def factory(total: int):
        nonlocal bar
        bar = tqdm(total=total, unit="ep", desc="episodes", disable=args.no_progress)
        return bar.update

    index = generate_dataset(
        args.out,
        pools,
        seed=args.seed,
        split_seed=args.split_seed,
        train_episodes_per_game=args.episodes_per_game,
        max_games=args.max_games,
        max_steps=args.max_steps,
        splits=tuple(s for s in SPLITS if s in args.splits),
        text_source=source,
        progress_factory=factory,
    )
    if bar is not None:
        bar.close()
    summary = {k: {"episodes": v["episodes"], "observations": v["observations"]} for k, v in index["splits"].items()}
    print(json.dumps({"out": str(args.out), "seconds": index["seconds"], "splits": summary}, indent=2))
    return 0
