"""What every `lwm` command module shares: the parser class, value checks, dataclass options."""

from __future__ import annotations

import argparse
import dataclasses
import types
import typing
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, NoReturn, TypeVar

T = TypeVar("T")


class HelpFormatter(argparse.HelpFormatter):
    """Appends each option's default to its help, unless the help already says it, and the choices
    that a metavar hides."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if action.choices is not None and action.metavar is not None:  # the metavar hides the choices
            text += " (one of: %(choices)s)"
        default = action.default
        if not action.option_strings or action.required or "default" in text:
            return text
        if isinstance(action, argparse.BooleanOptionalAction):
            shown = action.option_strings[0 if default else -1]  # the flag that is in effect
        elif default is None or default is False or default is argparse.SUPPRESS:
            return text  # an absent option; its help says what that means
        elif isinstance(default, list | tuple):
            shown = " ".join(map(str, default))
        else:
            shown = str(default)
        return f"{text} (default: {shown.replace('%', '%%')})"


class LwmParser(argparse.ArgumentParser):
    """The parser of `lwm` and of every subcommand (argparse makes subparsers of the parent's class).

    Errors are one line, `lwm train: error: ...`, without the usage block, so that every bad input
    of every command reads the same way as the errors raised while the command runs.

    `arguments=add` defers `add(parser)` to the first parse or help of this parser: options built
    from dataclasses of torch-importing modules (TrainArgs, Budget) then cost the other commands
    nothing, and a command whose modules do not import still leaves the others working.
    """

    def __init__(self, *args: Any, arguments: Callable[[LwmParser], None] | None = None, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)
        self._deferred = arguments

    def add_deferred_arguments(self) -> None:
        if self._deferred is not None:
            add, self._deferred = self._deferred, None
            add(self)

    def parse_known_args(
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        self.add_deferred_arguments()
        return super().parse_known_args(args, namespace)

    def format_usage(self) -> str:
        self.add_deferred_arguments()
        return super().format_usage()

    def format_help(self) -> str:
        self.add_deferred_arguments()
        return super().format_help()

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


# --------------------------------------------------------------------------- value checks
# argparse turns an ArgumentTypeError into `argument --flag: <message>`.
def _number(text: str, kind: type) -> Any:
    try:
        return kind(text)
    except ValueError:
        noun = "an integer" if kind is int else "a number"
        raise argparse.ArgumentTypeError(f"must be {noun}, got {text!r}") from None


def positive_int(text: str) -> int:
    value = _number(text, int)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def nonnegative_int(text: str) -> int:
    value = _number(text, int)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def positive_float(text: str) -> float:
    value = _number(text, float)
    if not value > 0:  # also rejects nan
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def nonnegative_float(text: str) -> float:
    value = _number(text, float)
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def fraction(text: str) -> float:
    """A probability or rate in [0, 1]."""
    value = _number(text, float)
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"must be in [0, 1], got {text}")
    return value


def existing_dir(text: str) -> Path:
    """A directory that must exist, checked before any model or dataset is loaded."""
    path = Path(text)
    if not path.is_dir():
        raise argparse.ArgumentTypeError(f"no such directory: {text}")
    return path


def existing_dir_text(text: str) -> str:
    """`existing_dir`, kept as text: for a dataclass field that is recorded in JSON (run configs)."""
    return str(existing_dir(text))


def checkpoint_dir(text: str) -> Path:
    """A world-model checkpoint directory: its config.json is looked for before torch loads."""
    path = Path(text)
    if not (path / "config.json").is_file():
        raise argparse.ArgumentTypeError(f"{text} is not a checkpoint (no config.json)")
    return path


# --------------------------------------------------------------------------- dataclass options
def add_dataclass_arguments(
    parser: argparse.ArgumentParser,
    cls: type,
    *,
    only: Iterable[str] | None = None,
    extra: dict[str, dict[str, Any]] | None = None,
) -> None:
    """One `--field-name` option per field of the dataclass `cls` (or per field named in `only`).

    The type comes from the field's annotation (int, float, str, or one of them `| None`; bool
    becomes --flag/--no-flag), the help from `metadata["help"]` on the field, the default from the
    field; a field without a default is a required option. `extra[name]` adds or overrides
    add_argument keywords, e.g. choices or a range-checking type.
    """
    hints = typing.get_type_hints(cls)
    wanted = None if only is None else set(only)
    extra = extra or {}
    unknown = set(extra) - {f.name for f in dataclasses.fields(cls)}
    if unknown:
        raise TypeError(f"{cls.__name__} has no field(s) {sorted(unknown)}")
    for f in dataclasses.fields(cls):
        if wanted is not None and f.name not in wanted:
            continue
        kind = hints[f.name]
        if typing.get_origin(kind) in (types.UnionType, typing.Union):
            members = [t for t in typing.get_args(kind) if t is not type(None)]
            if len(members) != 1:
                raise TypeError(f"{cls.__name__}.{f.name}: no option for the type {kind}")
            kind = members[0]
        if kind not in (int, float, str, bool):
            raise TypeError(f"{cls.__name__}.{f.name}: no option for the type {kind}")
        text = f.metadata.get("help")
        if not text:
            raise TypeError(f"{cls.__name__}.{f.name} has no metadata['help'] to show in --help")
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        options: dict[str, Any] = {"dest": f.name, "help": text.replace("%", "%%")}
        if kind is bool:
            options.update(action=argparse.BooleanOptionalAction, default=f.default)
        else:
            options.update(type=kind, required=required, default=None if required else f.default)
            if "choices" not in extra.get(f.name, {}):
                options["metavar"] = {int: "N", float: "X", str: "TEXT"}[kind]
        options.update(extra.get(f.name, {}))
        parser.add_argument("--" + f.name.replace("_", "-"), **options)


def dataclass_from_args(cls: type[T], args: argparse.Namespace) -> T:
    """The dataclass `cls` from parsed options that `add_dataclass_arguments` declared (other
    attributes of `args`, such as the subcommand's, are left out)."""
    fields = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in vars(args).items() if k in fields})
