"""`lwm`: the project's command line.

Every command is one module of this package with a `register(subparsers)` function that adds its
parser and sets `func`, the handler; see README.md for the list. Other installed packages add
commands through the entry-point group `lwm_models.commands` (e.g. `ros`, from lwm_nodes).

Errors in the user's input exit with status 2 and a one-line message, not a traceback.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
from collections.abc import Iterable
from importlib.metadata import EntryPoint, entry_points

from ..errors import LwmError
from . import agent, data, export, imagine, ledger, parser_accuracy, play, recipes, train, tune_reader
from . import eval as evaluate
from .args import LwmParser

COMMANDS = (data, play, train, tune_reader, evaluate, imagine, export, parser_accuracy, agent, ledger)
PLUGIN_GROUP = "lwm_models.commands"
ROS_HINT = "the ROS 2 nodes are not installed{why}; run ./run_nodes.sh once"


def _placeholder(subparsers: argparse._SubParsersAction, name: str, summary: str, message: str) -> None:
    """A command whose package is missing: it takes any arguments and explains what to install."""

    def explain(args: argparse.Namespace) -> int:
        print(f"lwm {name}: error: {message}", file=sys.stderr)
        return 2

    p = subparsers.add_parser(name, help=summary, description=message, add_help=False)
    p.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    p.set_defaults(func=explain, takes_any_arguments=True)


def installed_plugins() -> Iterable[EntryPoint]:
    return entry_points(group=PLUGIN_GROUP)


def add_plugins(subparsers: argparse._SubParsersAction, plugins: Iterable[EntryPoint]) -> None:
    """The commands of other packages, each entry point a `register(subparsers)` callable.

    A plugin that fails to load becomes a placeholder naming the error: one broken package must not
    take down every `lwm` command. `ros` is always there, as a hint when lwm_nodes is missing.
    """
    for point in plugins:
        if point.name in subparsers.choices:  # the core's own commands win
            continue
        try:
            point.load()(subparsers)
        except Exception as exc:  # any failure of the other package, at import or at registration
            if point.name in subparsers.choices:
                continue
            message = f"cannot load the command from {point.value} ({exc})"
            if point.name == "ros":
                message = ROS_HINT.format(why=f" ({exc})")
            _placeholder(subparsers, point.name, f"not available: {message}", message)
    if "ros" not in subparsers.choices:
        why = ""
        if importlib.util.find_spec("lwm_nodes") is not None:  # installed before it declared the entry point
            why = f" (lwm_nodes declares no {PLUGIN_GROUP} entry point: reinstall it)"
        _placeholder(subparsers, "ros", "ROS 2 graph tools (needs the ROS 2 nodes installed)", ROS_HINT.format(why=why))


def build_parser(plugins: Iterable[EntryPoint] | None = None) -> LwmParser:
    """The parser of `lwm`, with the commands of `plugins` (default: the installed entry points)."""
    parser = LwmParser(prog="lwm", description="Language-guided world models on Messenger-WM.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        command.register(sub)
    add_plugins(sub, installed_plugins() if plugins is None else plugins)
    return parser


# glibc's default malloc returns training's large tensors to the kernel and maps them again at
# every step (measured: 1.4-1.7x slower). These tunables keep freed memory in the process; they
# must be set before Python starts, so `lwm train` re-executes itself once with them.
ALLOCATOR_TUNABLES = (
    "glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=17179869184:glibc.malloc.top_pad=1073741824"
)


def _reexec_with_allocator_tunables(argv: list[str]) -> None:
    if os.environ.get("LWM_NO_ALLOCATOR_TUNING") or "GLIBC_TUNABLES" in os.environ:
        return
    env = {**os.environ, "GLIBC_TUNABLES": ALLOCATOR_TUNABLES}
    os.execve(sys.executable, [sys.executable, "-m", "lwm_models.cli.main", *argv], env)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser()
    try:
        expanded = recipes.expand(parser, argv)
    except recipes.RecipeError as exc:
        command = " ".join(t for t in argv[:2] if not t.startswith("-"))
        print(f"lwm {command}: error: {exc}", file=sys.stderr)
        return 2
    try:
        args, rest = parser.parse_known_args(expanded)
        if rest and not getattr(args, "takes_any_arguments", False):
            parser.error(f"unrecognized arguments: {' '.join(rest)}")
    except SystemExit as exc:  # argparse has printed the help or the one-line error
        return 0 if exc.code is None else exc.code if isinstance(exc.code, int) else 2
    if args.command == "train" and "WORLD_SIZE" not in os.environ:
        _reexec_with_allocator_tunables(argv)
    try:
        return int(args.func(args) or 0)
    except (LwmError, OSError) as exc:
        print(f"lwm: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
