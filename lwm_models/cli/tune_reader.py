"""`lwm tune-reader`: teach EMMA-LWM's reader other words, its decoder kept (resumes a run)."""

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
        "tune-reader",
        help="teach EMMA-LWM's reader other words; its decoder, and so its imagination, is kept",
        description="Fine-tune only how an EMMA-LWM checkpoint reads descriptions (lwm_models/world/reader_tuning.py); "
        "running it again resumes the run in --out.",
        arguments=add_arguments,
    )
    p.set_defaults(func=run)


def add_arguments(p: LwmParser) -> None:
    from ..text.free_form import MIX_SOURCES
    from ..world.reader_tuning import ReaderTuningArgs

    checks = {
        "steps": positive_int,
        "batch": positive_int,
        "lr": positive_float,
        "warmup": nonnegative_int,
        "weight_decay": nonnegative_float,
        "clip": positive_float,
        "max_tokens": positive_int,
        "mix_per_style": positive_int,
        "token_drop": fraction,
        "eval_every": positive_int,
        "eval_episodes": positive_int,
        "threads": positive_int,
        "max_minutes": positive_float,
    }
    extra = {name: {"type": check} for name, check in checks.items()}
    extra["init"] = {"type": existing_dir_text, "metavar": "CHECKPOINT"}
    extra["data"] = {"type": existing_dir_text, "metavar": "DIR"}
    extra["out"] = {"metavar": "RUN"}
    extra["mix_source"] = {"choices": list(MIX_SOURCES)}
    add_dataclass_arguments(p, ReaderTuningArgs, extra=extra)
    add_config_option(p)


def run(args: argparse.Namespace) -> int:
    from ..world.reader_tuning import ReaderTuningArgs, tune_reader

    print(json.dumps(tune_reader(dataclass_from_args(ReaderTuningArgs, args))))
    return 0
