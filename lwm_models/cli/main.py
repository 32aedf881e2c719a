"""`lwm`: the project's command line.

    lwm data splits [--seed N] [--out FILE]
    lwm data generate --out DIR [--text-source generated|PATH ...] [--seed N] [--episodes-per-game N]
    lwm play [--split S] [--index I] ...
    lwm train --data DIR --out RUN [--kind emma] [--preset paper] ...
    lwm eval --checkpoint DIR --data DIR [--out results.json] [--plot loss.png] [--texts PATH ...]
    lwm imagine --checkpoint DIR [--split S --index I] [--policy go_to_goal | --actions 3,3,1] ...

Errors in the user's input exit with status 2 and a one-line message, not a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ..errors import LwmError
from ..messenger.constants import DEFAULT_MAX_STEPS


def _cmd_splits(args: argparse.Namespace) -> int:
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


def _cmd_generate(args: argparse.Namespace) -> int:
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
        text_source=source,
        progress_factory=factory,
    )
    if bar is not None:
        bar.close()
    summary = {k: {"episodes": v["episodes"], "observations": v["observations"]} for k, v in index["splits"].items()}
    print(json.dumps({"out": str(args.out), "seconds": index["seconds"], "splits": summary}, indent=2))
    return 0


def _add_dataclass_args(p: argparse.ArgumentParser, cls) -> None:
    """One --flag per field of a dataclass, typed from its annotation (documented in TrainArgs)."""
    import dataclasses

    for f in dataclasses.fields(cls):
        flag = "--" + f.name.replace("_", "-")
        required = f.default is dataclasses.MISSING
        kind = str(f.type)
        if kind == "bool":
            p.add_argument(flag, action=argparse.BooleanOptionalAction, default=f.default)
            continue
        conv = int if "int" in kind and "float" not in kind else float if "float" in kind else str
        p.add_argument(
            flag,
            type=conv,
            required=required,
            default=None if required else f.default,
            help=f"default: {f.default}" if not required else "required",
        )


def _cmd_train(args: argparse.Namespace) -> int:
    import dataclasses

    from ..world.train import TrainArgs, train

    fields = {f.name for f in dataclasses.fields(TrainArgs)}
    result = train(TrainArgs(**{k: v for k, v in vars(args).items() if k in fields}))
    print(json.dumps(result))
    return 0


def _cmd_parser_accuracy(args: argparse.Namespace) -> int:
    from ..text import load_description_file
    from ..text.parser import parser_accuracy

    rows = {str(path): parser_accuracy(load_description_file(path)) for path in args.texts}
    for path, acc in rows.items():
        print(
            f"{path}: {acc['descriptions']} descriptions; identity {acc['identity']:.1%}, "
            f"movement {acc['movement']:.1%}, role {acc['role']:.1%}"
        )
    return 0


def _cmd_ledger_show(args: argparse.Namespace) -> int:
    from ..ledger import Ledger, describe

    if not args.path.is_file():
        raise LwmError(f"no ledger at {args.path}")
    ledger = Ledger(args.path)
    reviews = [args.review] if args.review else ledger.reviews()
    for review in reviews:
        records = ledger.history(review)
        if not records:
            raise LwmError(f"no review {review!r} in {args.path}")
        print(f"review {review}")
        for r in records:
            print("  " + describe(r))
    return 0


def _cmd_agent_pretrain(args: argparse.Namespace) -> int:
    import time

    import torch
    from tqdm import tqdm

    from ..agent.learning import pretrain
    from ..agent.policy import EmmaPolicy, save_policy
    from ..data.dataset import TrajectoryDataset
    from ..world.frozen_text import FrozenTextEncoder

    torch.manual_seed(args.seed)
    if args.threads:
        torch.set_num_threads(args.threads)
    data = TrajectoryDataset(args.data, "train")
    feats, lengths = FrozenTextEncoder().encode_arrays(data.texts)
    policy = EmmaPolicy()
    bar = tqdm(total=args.steps, desc="behaviour cloning", disable=args.no_progress)
    args.out.mkdir(parents=True, exist_ok=True)
    log = open(args.out / "metrics.jsonl", "w")

    def progress(step: int, loss: float) -> None:
        bar.update(1)
        if step % 100 == 0:
            log.write(json.dumps({"step": step, "loss": loss, "seed": args.seed}) + "\n")
            log.flush()

    began = time.perf_counter()
    losses = pretrain(
        policy,
        data,
        torch.from_numpy(feats),
        torch.from_numpy(lengths),
        steps=args.steps,
        batch=args.batch,
        lr=args.lr,
        seed=args.seed,
        progress=progress,
    )
    bar.close()
    save_policy(
        policy,
        args.out,
        {
            "trained": {
                "command": "lwm agent pretrain",
                "data": str(args.data),
                "steps": args.steps,
                "batch": args.batch,
                "lr": args.lr,
                "seed": args.seed,
                "final_loss": float(np.mean(losses[-100:])),
                "seconds": round(time.perf_counter() - began, 1),
            }
        },
    )
    print(json.dumps({"out": str(args.out), "final_loss": float(np.mean(losses[-100:]))}))
    return 0


def _cmd_table3(args: argparse.Namespace) -> int:
    from ..agent.cli_table3 import run_table3

    return run_table3(args)


def _cmd_export(args: argparse.Namespace) -> int:
    import torch

    from ..world.checkpoint import load_checkpoint, save_checkpoint

    model, config = load_checkpoint(args.checkpoint)
    keep = {
        k: v
        for k, v in config.items()
        if k not in ("format", "version", "kind", "config", "dtype", "sha256", "parameters")
    }
    keep["exported_from"] = str(args.checkpoint)
    save_checkpoint(model, args.out, keep, dtype=torch.float16 if args.fp16 else None)
    size = (args.out / "model.safetensors").stat().st_size
    print(f"exported {config['kind']} to {args.out} ({size / 1e6:.1f} MB)")
    return 0


def _cmd_eval(args: argparse.Namespace) -> int:
    from ..world.cli_eval import run_eval

    return run_eval(args)


def _cmd_imagine(args: argparse.Namespace) -> int:
    from ..world.cli_imagine import run_imagine

    return run_imagine(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lwm", description="Language-guided world models on Messenger-WM.")
    sub = parser.add_subparsers(dest="command", required=True)

    data = sub.add_parser("data", help="the Messenger-WM benchmark: game splits and trajectories")
    data_sub = data.add_subparsers(dest="data_command", required=True)

    p = data_sub.add_parser("splits", help="generate the game splits and print their counts")
    p.add_argument("--seed", type=int, default=0, help="seed of the split generator")
    p.add_argument("--out", type=Path, default=None, help="also write the splits to this JSON file")
    p.set_defaults(func=_cmd_splits)

    p = data_sub.add_parser("generate", help="generate the trajectory dataset")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument(
        "--text-source",
        nargs="+",
        default=["generated"],
        help="'generated' (the project's own descriptions) or human-written description JSON file(s)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of episodes, policies and manuals")
    p.add_argument("--split-seed", type=int, default=0, help="seed of the game splits")
    p.add_argument("--episodes-per-game", type=int, default=66, help="training episodes per training game")
    p.add_argument("--max-games", type=int, default=None, help="keep only the first N games of each split")
    p.add_argument("--max-steps", type=int, default=DEFAULT_MAX_STEPS, help="time limit in actions")
    p.add_argument("--typo-rate", type=float, default=0.0, help="typo rate of generated descriptions")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_generate)

    from ..world.train import TrainArgs

    p = sub.add_parser("train", help="train a world model (resumes when the run directory has one)")
    _add_dataclass_args(p, TrainArgs)
    p.set_defaults(func=_cmd_train)

    p = sub.add_parser("eval", help="evaluate a world model: cross-entropy and imagination metrics")
    p.add_argument("--checkpoint", type=Path, required=True, help="checkpoint directory")
    p.add_argument("--data", type=Path, required=True, help="dataset directory")
    p.add_argument("--splits", nargs="+", default=["newcombo-test", "newattr-test", "newall-test"])
    p.add_argument("--loss-episodes", type=int, default=None, help="episodes per split for CE (default all)")
    p.add_argument("--imagination-episodes", type=int, default=200, help="episodes per split to imagine (0: skip)")
    p.add_argument("--texts", nargs="+", default=None, help="re-draw the manuals from these description files")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=None, help="write the results as JSON here")
    p.add_argument("--plot", type=Path, default=None, help="write loss against history length as PNG here")
    p.set_defaults(func=_cmd_eval)

    ledger = sub.add_parser("ledger", help="the review ledger")
    ledger_sub = ledger.add_subparsers(dest="ledger_command", required=True)
    p = ledger_sub.add_parser("show", help="print the history of a review (default: every review)")
    p.add_argument("--path", type=Path, default=Path("logs/ledger.sqlite"), help="ledger file")
    p.add_argument("--review", default=None, help="review id")
    p.set_defaults(func=_cmd_ledger_show)

    agent = sub.add_parser("agent", help="the plan-review agent's policy")
    agent_sub = agent.add_subparsers(dest="agent_command", required=True)
    p = agent_sub.add_parser("pretrain", help="behaviour-clone the expert on the training games (warm start)")
    p.add_argument("--data", type=Path, required=True, help="dataset directory")
    p.add_argument("--out", type=Path, required=True, help="policy directory to write")
    p.add_argument("--steps", type=int, default=5000, help="optimizer steps")
    p.add_argument("--batch", type=int, default=128, help="states per step (expert-labelled on the fly)")
    p.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate")
    p.add_argument("--seed", type=int, default=0, help="seeds the init and the sampling of states")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_agent_pretrain)

    p = agent_sub.add_parser("table3", help="the paper's Table 3 on N test games per split")
    from ..agent.cli_table3 import add_arguments

    add_arguments(p)
    p.set_defaults(func=_cmd_table3)

    p = sub.add_parser("export", help="copy a checkpoint for shipping (optionally fp16)")
    p.add_argument("--checkpoint", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--fp16", action="store_true", help="store the weights as float16")
    p.set_defaults(func=_cmd_export)

    p = sub.add_parser("parser-accuracy", help="accuracy of the offline description parser (GPTHard's router)")
    p.add_argument("--texts", nargs="+", type=Path, required=True, help="human-written description files")
    p.set_defaults(func=_cmd_parser_accuracy)

    p = sub.add_parser("imagine", help="imagine trajectories of a game with a world model")
    p.add_argument("--checkpoint", type=Path, default=None, help="checkpoint directory (default: shipped EMMA-LWM)")
    p.add_argument("--split", default="newall-test", help="split of the game")
    p.add_argument("--index", type=int, default=0, help="game index in the split")
    p.add_argument("--seed", type=int, default=0, help="seed of the real first observation and the sampling")
    p.add_argument("--n", type=int, default=1, help="number of trajectories")
    p.add_argument("--policy", default="go_to_goal", help="behaviour policy that acts in imagination")
    p.add_argument("--actions", default=None, help="comma-separated actions 0-4 instead of a policy")
    p.add_argument("--max-steps", type=int, default=DEFAULT_MAX_STEPS)
    p.add_argument("--texts", nargs="+", default=None, help="draw the manual from these description files")
    p.add_argument("--png", type=Path, default=None, help="write the first trajectory as a PNG strip")
    p.add_argument("--json", action="store_true", help="print the trajectories as JSON")
    p.set_defaults(func=_cmd_imagine)

    sub.add_parser("play", help="play a Messenger game in the terminal (lwm play --help)", add_help=False)
    sub.add_parser("ros", help="ROS 2 graph tools: nodes, topics, services, pub, echo, call (lwm ros --help)")
    return parser


def _play(rest: list[str]) -> int:
    from .play import play_main

    return play_main(rest)


# glibc's default malloc returns training's large tensors to the kernel and maps them again at
# every step (measured: 1.4-1.7x slower). These tunables keep freed memory in the process; they
# must be set before Python starts, so `lwm train` re-executes itself once with them.
ALLOCATOR_TUNABLES = (
    "glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=17179869184:glibc.malloc.top_pad=1073741824"
)


def _reexec_with_allocator_tunables(argv: list[str]) -> None:
    import os

    if os.environ.get("LWM_NO_ALLOCATOR_TUNING") or "GLIBC_TUNABLES" in os.environ:
        return
    env = {**os.environ, "GLIBC_TUNABLES": ALLOCATOR_TUNABLES}
    os.execve(sys.executable, [sys.executable, "-m", "lwm_models.cli.main", *argv], env)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["play"]:  # play has its own parser; argparse.REMAINDER would drop its options
        return _play(argv[1:])
    if argv[:1] == ["ros"]:  # the ROS tools live with the nodes: the core never imports rclpy
        try:
            from lwm_nodes.ros_cli import main as ros_main
        except ImportError as exc:
            print(
                f"lwm ros: error: the ROS 2 nodes are not installed ({exc}); run ./run_nodes.sh once", file=sys.stderr
            )
            return 2
        return ros_main(argv[1:])
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == "train" and "WORLD_SIZE" not in __import__("os").environ:
        _reexec_with_allocator_tunables(argv)
    for name in ("episodes_per_game", "max_games", "max_steps"):
        value = getattr(args, name, None)
        if value is not None and value < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {value}")
    try:
        return int(args.func(args) or 0)
    except (LwmError, OSError) as exc:
        print(f"lwm: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
