"""`lwm train`: train a world model, or resume the run in its directory."""

from __future__ import annotations

import argparse
import json

from .args import (
    LwmParser,
    add_dataclass_arguments,
    dataclass_from_args,
    existing_dir_text,
    fraction,
    nonnegative_float,
    nonnegative_int,
    positive_float,
    positive_int,
)
from .recipes import add_config_option


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "train",
        help="train a world model (resumes when the run directory has one)",
        description="Train a world model on a dataset; running it again resumes the run in --out.",
        arguments=add_arguments,
    )
    p.set_defaults(func=run)


def add_arguments(p: LwmParser) -> None:
    from ..messenger.constants import SPLITS
    from ..text.free_form import MIX_SOURCES
    from ..world.registry import KINDS, PRESETS
    from ..world.train import SELECTIONS, TrainArgs

    checks = {
        "steps": positive_int,
        "batch": positive_int,
        "lr": positive_float,
        "warmup": nonnegative_int,
        "weight_decay": nonnegative_float,
        "clip": positive_float,
        "seed": nonnegative_int,
        "eval_every": positive_int,
        "eval_episodes": positive_int,
        "attn_dropout": fraction,
        "kv_heads": positive_int,
        "threads": positive_int,
        "parts": positive_int,
        "max_tokens": positive_int,
        "manual_mix": fraction,
        "mix_per_style": positive_int,
        "max_minutes": positive_float,
        "cpu_budget_minutes": positive_float,
        "distill_weight": positive_float,
        "event_weight": positive_float,
        "select_episodes": positive_int,
    }
    extra = {name: {"type": check} for name, check in checks.items()}
    extra["data"] = {"type": existing_dir_text, "metavar": "DIR"}
    extra["out"] = {"metavar": "RUN"}
    extra["init"] = {"type": existing_dir_text, "metavar": "CHECKPOINT"}
    extra["distill"] = {"type": existing_dir_text, "metavar": "CHECKPOINT"}
    extra["select"] = {"choices": list(SELECTIONS)}
    extra["mix_source"] = {"choices": list(MIX_SOURCES)}
    extra["kind"] = {"choices": list(KINDS)}
    extra["preset"] = {"choices": list(PRESETS)}
    extra["eval_split"] = {"choices": list(SPLITS), "metavar": "SPLIT"}
    add_dataclass_arguments(p, TrainArgs, extra=extra)
    add_config_option(p)


def run(args: argparse.Namespace) -> int:
    from ..world.train import TrainArgs, train

    print(json.dumps(train(dataclass_from_args(TrainArgs, args))))
    return 0
