"""`lwm agent table3`: the paper's Table 3 on N test games per split, with the shipped models."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from ..agent.table3 import SETTINGS
from ..errors import LwmError
from ..messenger.constants import SPLITS as ALL_SPLITS
from .args import LwmParser, add_dataclass_arguments, nonnegative_int, positive_float, positive_int

PAPER = {  # real return, the paper's Table 3 (30 games per split)
    ("online_il", "observational"): (0.75, -0.41, -0.21),
    ("online_il", "emma"): (1.01, 0.96, 0.62),
    ("online_il", "oracle"): (1.04, 0.85, 0.91),
    ("filtered_bc", "observational"): (0.77, -0.42, -0.30),
    ("filtered_bc", "emma"): (1.18, 0.75, 0.44),
    ("filtered_bc", "oracle"): (1.17, 0.84, 0.80),
    # the suboptimal expert: only NewAll's figures are at hand (the paper's Table 3)
    ("filtered_bc_suboptimal", "observational"): (None, None, -0.33),
    ("filtered_bc_suboptimal", "emma"): (None, None, 0.13),
    ("filtered_bc_suboptimal", "oracle"): (None, None, 0.49),
}
SPLITS = ("newcombo-test", "newattr-test", "newall-test")
BUDGET_OPTIONS = ("iterations", "episodes", "grad_steps", "batch", "lr", "plans_per_start", "overlap", "constrained")
RECORD_KEYS = ("setting", "model", "split", "game", "return", "learn_seconds")


def register(agent_subparsers: argparse._SubParsersAction) -> None:
    p = agent_subparsers.add_parser(
        "table3",
        help="the paper's Table 3 on N test games per split",
        description="Learn in imagination on N test games per split and act in the real games.",
        arguments=add_arguments,
    )
    p.set_defaults(func=run_table3)


def add_arguments(p: LwmParser) -> None:
    from ..agent.learning import Budget

    p.add_argument("--data", type=Path, required=True, help="dataset directory (test games and their manuals)")
    p.add_argument("--games", type=positive_int, default=30, help="test games per split (the paper: 30)")
    p.add_argument(
        "--splits", nargs="+", choices=ALL_SPLITS, default=list(SPLITS), metavar="SPLIT", help="splits of the games"
    )
    p.add_argument(
        "--models",
        nargs="+",
        default=None,
        metavar="NAME=CHECKPOINT",
        help="NAME=CHECKPOINT pairs (default: the shipped emma, observational and oracle)",
    )
    p.add_argument(
        "--settings",
        nargs="+",
        default=["online_il", "filtered_bc"],
        choices=list(SETTINGS),
        metavar="SETTING",
        help="how the agent learns: online imitation, filtered behaviour cloning of the near-optimal or the "
        "suboptimal expert's best imagined plans, or the warm-start policy alone",
    )
    p.add_argument("--policy", type=Path, default=None, help="warm-start policy (default: shipped, else untrained)")
    checks = {"iterations": positive_int, "episodes": positive_int, "grad_steps": positive_int, "batch": positive_int}
    checks |= {"lr": positive_float, "plans_per_start": positive_int}
    add_dataclass_arguments(
        p, Budget, only=BUDGET_OPTIONS, extra={name: {"type": check} for name, check in checks.items()}
    )
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seed of game g is this + g")
    p.add_argument(
        "--threads",
        type=positive_int,
        default=1,
        help="torch threads. 1 (the default) makes a record a function of the command and seed alone: with 2 "
        "threads on a loaded 2-core machine, NewAll game 0 gave +0.66 and +0.61 in two runs of one command, "
        "with 1 thread +0.60 every time. Each record keeps its thread count.",
    )
    p.add_argument("--out", type=Path, default=None, help="write the table as JSON")
    p.add_argument(
        "--records",
        type=Path,
        default=None,
        help="JSONL of per-game results, appended as each game finishes; games already in it are skipped "
        "(resume, or split the work over processes and merge the files with --from-records)",
    )
    p.add_argument("--from-records", type=Path, nargs="+", default=None, help="only print the table of these files")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _budget(args: argparse.Namespace):
    from ..agent.learning import Budget

    return Budget(
        iterations=args.iterations,
        episodes=args.episodes,
        grad_steps=args.grad_steps,
        batch=args.batch,
        lr=args.lr,
        plans_per_start=args.plans_per_start,
        overlap=args.overlap,
        constrained=args.constrained,
    )


def _load_records(paths: list[Path]) -> list[dict]:
    records = []
    for path in paths:
        if not path.is_file():
            continue
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if not line.strip():
                continue
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                raise LwmError(f"{path}:{n}: not a JSON record") from None
            if not isinstance(record, dict) or any(key not in record for key in RECORD_KEYS):
                raise LwmError(f"{path}:{n}: not a Table 3 record (it needs {', '.join(RECORD_KEYS)})")
            records.append(record)
    return records


def table(records: list[dict]) -> dict:
    """Mean and 95% interval per (setting/model, split) over the recorded games."""
    from ..agent.table3 import summarize

    rows: dict = {}
    for key in sorted({(r["setting"], r["model"]) for r in records}):
        row = rows.setdefault(f"{key[0]}/{key[1]}", {})
        for split in SPLITS:
            games = [r for r in records if (r["setting"], r["model"], r["split"]) == (*key, split)]
            if games:
                row[split] = {
                    **summarize([r["return"] for r in games]),
                    "learn_seconds_per_game": round(float(np.mean([r["learn_seconds"] for r in games])), 2),
                }
    return rows


def print_table(rows: dict) -> None:
    print("Table 3: mean real return over the test games of each split (95% t interval over games); paper in brackets")
    print(f"{'setting / model':<28}" + "".join(f"{s:>36}" for s in SPLITS))
    for key, row in rows.items():
        setting, name = key.split("/")
        paper = PAPER.get((setting, name))
        cells = []
        for i, split in enumerate(SPLITS):
            r = row.get(split)
            ref = f" [{paper[i]:+.2f}]" if paper and paper[i] is not None else ""
            cells.append(
                "-" if r is None else f"{r['mean']:+.2f} ({r['ci95'][0]:+.2f},{r['ci95'][1]:+.2f}) n{r['games']}{ref}"
            )
        print(f"{key:<28}" + "".join(f"{c:>36}" for c in cells))


def run_table3(args: argparse.Namespace) -> int:
    if args.from_records:
        missing = [p for p in args.from_records if not p.is_file()]
        if missing:
            raise LwmError(f"no such records file: {missing[0]}")
        rows = table(_load_records(args.from_records))
        print_table(rows)
        if args.out:
            args.out.write_text(json.dumps({"rows": rows}, indent=2))
        return 0
    if not args.data.is_dir():  # before the models load, which takes seconds
        raise LwmError(f"no such dataset directory: {args.data}")

    import torch
    from tqdm import tqdm

    from ..agent.policy import EmmaPolicy, load_policy
    from ..agent.table3 import evenly_spaced_games, run_game
    from ..data.dataset import TrajectoryDataset
    from ..world.checkpoint import load_checkpoint
    from ..world.frozen_text import FrozenTextEncoder
    from ..world.shipped import SHIPPED_POLICY, table3_defaults

    torch.set_num_threads(args.threads)
    models = {}
    pairs = args.models or [f"{k}={v}" for k, v in table3_defaults().items()]
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
    budget = _budget(args)
    earlier = _load_records([args.records] if args.records and args.records.is_file() else [])
    defaults = type(budget)().__dict__
    for r in earlier:  # resuming must not mix figures learnt under another budget into one table
        theirs = {k: r.get("budget", {}).get(k, v) for k, v in defaults.items()}
        if theirs != budget.__dict__:
            changed = sorted(k for k in defaults if theirs[k] != budget.__dict__[k])
            raise LwmError(
                f"{args.records} holds records of another budget ({', '.join(changed)}); use another --records"
            )
        if r.get("threads", args.threads) != args.threads:
            raise LwmError(
                f"{args.records} holds records made with {r['threads']} torch thread(s), which give other figures "
                f"than {args.threads}; use --threads {r['threads']} or another --records"
            )
        # nor figures of another checkpoint under the same name (a re-shipped model)
        if r["model"] in models and r.get("checkpoint") != models[r["model"]][1].get("sha256"):
            raise LwmError(
                f"{args.records} holds records of {r['model']} from another checkpoint "
                f"({str(r.get('checkpoint', 'not recorded'))[:12]}); use another --records"
            )
    done = {(r["setting"], r["model"], r["split"], r["game"]) for r in earlier}
    began, began_cpu = time.perf_counter(), time.process_time()
    todo = []
    for split in args.splits:
        ds = TrajectoryDataset(args.data, split)
        games = evenly_spaced_games(len(ds.games), args.games)
        episode_games = np.asarray(ds.episode_games)
        for g in map(int, games):
            manual = ds[int(np.flatnonzero(episode_games == g)[0])].manual  # the game's first episode's
            for setting in args.settings:
                for name in models:
                    if (setting, name, split, g) not in done:
                        todo.append((split, ds.games[g], g, manual, setting, name))
    records = []
    for split, game, g, manual, setting, name in tqdm(todo, desc="table 3", disable=args.no_progress):
        world, config = models[name]
        result = run_game(setting, world, warm, game, manual, encoder, budget, args.seed + g)
        record = {"setting": setting, "model": name, "split": split, "game": g, "seed": args.seed + g, **result}
        record["budget"] = budget.__dict__
        record["threads"] = args.threads
        record["checkpoint"] = config.get("sha256")  # the weights' identity: resuming checks it
        records.append(record)
        if args.records:
            with args.records.open("a") as f:
                f.write(json.dumps(record) + "\n")
    wall, cpu = round(time.perf_counter() - began, 1), round(time.process_time() - began_cpu, 1)
    all_records = _load_records([args.records]) if args.records else records
    rows = table(all_records)
    print_table(rows)
    print(f"this run: {len(records)} game(s), {wall:.0f} s wall, {cpu:.0f} s CPU")
    if args.out:
        args.out.write_text(
            json.dumps(
                {"budget": budget.__dict__, "seed": args.seed, "wall_seconds": wall, "cpu_seconds": cpu, "rows": rows},
                indent=2,
            )
        )
    return 0
