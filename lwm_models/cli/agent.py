"""`lwm agent pretrain|table3`: the plan-review agent's policy, and the paper's Table 3."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from . import table3
from .args import existing_dir, nonnegative_int, positive_float, positive_int
from .recipes import add_config_option


def register(subparsers: argparse._SubParsersAction) -> None:
    agent = subparsers.add_parser("agent", help="the plan-review agent's policy")
    agent_sub = agent.add_subparsers(dest="agent_command", required=True)

    p = agent_sub.add_parser("pretrain", help="behaviour-clone the expert on the training games (warm start)")
    p.add_argument("--data", type=existing_dir, required=True, help="dataset directory")
    p.add_argument("--out", type=Path, required=True, help="policy directory to write")
    p.add_argument("--steps", type=positive_int, default=5000, help="optimizer steps")
    p.add_argument("--batch", type=positive_int, default=128, help="states per step (expert-labelled on the fly)")
    p.add_argument("--lr", type=positive_float, default=1e-3, help="Adam learning rate")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seeds the init and the sampling of states")
    p.add_argument("--threads", type=positive_int, default=None, help="torch threads (default: torch's)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_config_option(p)
    p.set_defaults(func=run_pretrain)

    table3.register(agent_sub)


def run_pretrain(args: argparse.Namespace) -> int:
    import time

    import numpy as np
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
