"""`lwm ledger show`: the history of the reviews in the review ledger."""

from __future__ import annotations

import argparse
import sqlite3
from pathlib import Path

from ..errors import LwmError
from ..run_dirs import DEFAULT_LEDGER


def register(subparsers: argparse._SubParsersAction) -> None:
    ledger = subparsers.add_parser("ledger", help="the review ledger")
    ledger_sub = ledger.add_subparsers(dest="ledger_command", required=True)
    p = ledger_sub.add_parser("show", help="print the history of a review (default: every review)")
    p.add_argument(
        "--path", type=Path, default=DEFAULT_LEDGER, help="ledger file (default: the newest run's, logs/latest)"
    )
    p.add_argument("--review", default=None, help="review id (default: every review)")
    p.set_defaults(func=run_show)


def run_show(args: argparse.Namespace) -> int:
    from ..ledger import Ledger, describe

    if not args.path.is_file():
        raise LwmError(f"no ledger at {args.path}")
    try:
        ledger = Ledger(args.path)
        reviews = [args.review] if args.review else ledger.reviews()
        histories = {review: ledger.history(review) for review in reviews}
    except sqlite3.DatabaseError as exc:  # e.g. "file is not a database"
        raise LwmError(f"{args.path} is not a ledger: {exc}") from None
    for review, records in histories.items():
        if not records:
            raise LwmError(f"no review {review!r} in {args.path}")
        print(f"review {review}")
        for r in records:
            print("  " + describe(r))
    return 0
