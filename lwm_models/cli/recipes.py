"""Named recipes: `lwm train --config configs/NAME.json` (and `lwm agent pretrain --config ...`).

A recipe is a JSON file of a command's options, so that the way each shipped model was trained is
one file that the README, the scripts and the docs can cite instead of a copy of its flags:

    {"command": "lwm train", "about": "...", "options": {"kind": "emma", "lr": 0.001, ...}}

`options` are keyed by the option's name with underscores (`eval_every` for `--eval-every`); a
`null` value leaves the command's default. The file's options are placed before the command line's
own, so anything given explicitly on the command line overrides the recipe. Every value goes
through the same check as on the command line, and a recipe that cannot be used is one line,
naming the file and the option, with status 2.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from ..errors import LwmError

OPTION = "--config"
KEYS = {"command", "about", "options"}


class RecipeError(LwmError):
    """A recipe file that cannot be used: missing, not JSON, or with an option the command refuses."""


def add_config_option(parser: argparse.ArgumentParser) -> None:
    # Only documents the option: `expand` replaces it by the file's options before parsing, so the
    # parsed value is never read.
    parser.add_argument(
        OPTION,
        metavar="FILE",
        help="a recipe (configs/*.json): its options come first, so options given here override them",
    )


def _subcommand(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser | None:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices.get(name)
    return None


def _take_config(argv: list[str]) -> tuple[str | None, list[str]]:
    """The recipe's path, and argv without the option; a second --config is refused."""
    path, rest, i = None, [], 0
    while i < len(argv):
        token = argv[i]
        value = None
        if token == OPTION:
            if i + 1 >= len(argv):
                raise RecipeError(f"{OPTION} needs a file")
            value, i = argv[i + 1], i + 2
        elif token.startswith(OPTION + "="):
            value, i = token.split("=", 1)[1], i + 1
        else:
            rest.append(token)
            i += 1
            continue
        if path is not None:
            raise RecipeError(f"{OPTION} given twice ({path}, {value}): one recipe per run")
        path = value
    return path, rest


def load(path: str | Path) -> dict[str, Any]:
    """The recipe in `path`, its shape checked (the option values are checked against a command)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise RecipeError(f"{path}: no such recipe file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RecipeError(f"{path}: cannot read it ({exc})") from None
    try:
        recipe = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RecipeError(f"{path}: not JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})") from None
    if not isinstance(recipe, dict):
        raise RecipeError(f"{path}: a recipe is a JSON object with 'command' and 'options'")
    unknown = sorted(set(recipe) - KEYS)
    if unknown:
        raise RecipeError(f"{path}: unknown key(s) {', '.join(unknown)} (a recipe has {', '.join(sorted(KEYS))})")
    if not isinstance(recipe.get("command"), str):
        raise RecipeError(f"{path}: 'command' must name the command, e.g. \"lwm train\"")
    if not isinstance(recipe.get("options"), dict):
        raise RecipeError(f"{path}: 'options' must be an object of option names and values")
    return recipe


def _tokens(action: argparse.Action, key: str, value: Any, path: Path) -> list[str]:
    """The command-line words that set `action` to `value`, checked as the command line would be."""
    flag = action.option_strings[0]
    where = f"{path}: option {key!r}"
    if isinstance(action, argparse.BooleanOptionalAction):
        if not isinstance(value, bool):
            raise RecipeError(f"{where} must be true or false, got {json.dumps(value)}")
        return [flag if value else next(s for s in action.option_strings if s.startswith("--no-"))]
    if isinstance(action, argparse._StoreTrueAction):
        if not isinstance(value, bool):
            raise RecipeError(f"{where} must be true or false, got {json.dumps(value)}")
        return [flag] if value else []
    if action.nargs in ("*", "+"):
        values = value if isinstance(value, list) else [value]
    else:
        values = [value]
    words = []
    for item in values:
        if isinstance(item, bool) or not isinstance(item, int | float | str):
            raise RecipeError(f"{where} must be a number or text, got {json.dumps(item)}")
        word = str(item)
        try:
            converted = action.type(word) if callable(action.type) else word
        except (argparse.ArgumentTypeError, ValueError, TypeError) as exc:
            raise RecipeError(f"{where}: {exc}") from None
        if action.choices is not None and converted not in action.choices:
            choices = ", ".join(map(str, action.choices))
            raise RecipeError(f"{where}: {item!r} is not one of {choices}")
        words.append(word)
    return [flag, *words]


def expand(parser: argparse.ArgumentParser, argv: list[str]) -> list[str]:
    """argv with `--config FILE` replaced by the recipe's options, placed before the user's own.

    Commands are the leading words that name subcommands (`train`, `agent pretrain`); a command
    line without --config comes back unchanged.
    """
    if not any(t == OPTION or t.startswith(OPTION + "=") for t in argv):
        return argv
    names, sub = [], parser
    while len(names) < len(argv):
        child = _subcommand(sub, argv[len(names)])
        if child is None:
            break
        names.append(argv[len(names)])
        sub = child
    if hasattr(sub, "add_deferred_arguments"):
        sub.add_deferred_arguments()
    if not any(OPTION in a.option_strings for a in sub._actions):
        return argv  # a command without recipes: argparse names the unknown option
    path, rest = _take_config(argv[len(names) :])
    assert path is not None
    recipe = load(path)
    command = " ".join(["lwm", *names])
    if recipe["command"] != command:
        raise RecipeError(f"{path}: a recipe for `{recipe['command']}`, not for `{command}`")
    by_dest = {
        a.dest: a
        for a in sub._actions
        if a.option_strings and a.dest not in ("help", "config") and not isinstance(a, argparse._HelpAction)
    }
    given = {t.split("=", 1)[0] for t in rest if t.startswith("--")}
    tokens: list[str] = []
    for key, value in recipe["options"].items():
        action = by_dest.get(key)
        if action is None:
            known = ", ".join(sorted(by_dest))
            raise RecipeError(f"{path}: `{command}` has no option {key!r} (its options: {known})")
        if value is None or given & set(action.option_strings):
            continue  # the default, or overridden on the command line (so not checked here)
        tokens += _tokens(action, key, value, Path(path))
    return [*names, *tokens, *rest]
