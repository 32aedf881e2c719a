"""`lwm parser-accuracy`: how well the offline description parser (GPTHard's router) reads human text."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("parser-accuracy", help="accuracy of the offline description parser (GPTHard's router)")
    p.add_argument("--texts", nargs="+", type=Path, default=[], metavar="PATH", help="human-written description files")
    p.add_argument(
        "--stress",
        action="store_true",
        help="also the project's stress set, per part (tune, dev, heldout) and style (lwm_models/text/stress_set.json)",
    )
    p.add_argument(
        "--encoder",
        action="store_true",
        help="let the frozen text encoder guess what no keyword rule decides (slower; GPTHard routes without it)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..text import load_description_file
    from ..text.parser import parser_accuracy
    from ..text.stress import PARTS, stress_styles, stress_texts

    if not args.texts and not args.stress:
        print("lwm parser-accuracy: give --texts PATH ... and/or --stress", file=sys.stderr)
        return 2
    encoder = None
    if args.encoder:
        from ..world.frozen_text import FrozenTextEncoder

        encoder = FrozenTextEncoder()
    rows = {str(path): parser_accuracy(load_description_file(path), encoder) for path in args.texts}
    if args.stress:
        for part in PARTS:
            rows[f"stress {part}"] = parser_accuracy(stress_texts(part), encoder)
            for style in stress_styles():
                rows[f"stress {part} {style}"] = parser_accuracy(stress_texts(part, style), encoder)
    for path, acc in rows.items():
        print(
            f"{path}: {acc['descriptions']} descriptions; identity {acc['identity']:.1%}, "
            f"movement {acc['movement']:.1%}, role {acc['role']:.1%}"
        )
    return 0
