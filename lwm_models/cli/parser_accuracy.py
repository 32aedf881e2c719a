"""`lwm parser-accuracy`: how well the offline description parser (GPTHard's router) reads human text."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("parser-accuracy", help="accuracy of the offline description parser (GPTHard's router)")
    p.add_argument(
        "--texts", nargs="+", type=Path, required=True, metavar="PATH", help="human-written description files"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..text import load_description_file
    from ..text.parser import parser_accuracy

    rows = {str(path): parser_accuracy(load_description_file(path)) for path in args.texts}
    for path, acc in rows.items():
        print(
            f"{path}: {acc['descriptions']} descriptions; identity {acc['identity']:.1%}, "
            f"movement {acc['movement']:.1%}, role {acc['role']:.1%}"
        )
    return 0
