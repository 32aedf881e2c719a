"""`lwm play`: play a Messenger game of a split in the terminal.

The point is to feel the game a world model has to learn: read the manual, work out which
sprite is which, fetch the message and bring it to the goal without touching the enemy.

Keys: arrow keys or w/a/s/d move, space, '.' or 'x' stays, q quits. On a terminal the keys act at
once (cbreak mode, restored on exit and on Ctrl-C); when stdin is a pipe or a file, lines are read
and every character of a line is one key, so a game can be scripted:

    printf 'ddss\\nq\\n' | lwm play --split newall-test --index 3 --start 0
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

from ..errors import LwmError
from ..messenger.constants import (
    ACTION_NAMES,
    DEFAULT_MAX_STEPS,
    DOWN,
    LEFT,
    RIGHT,
    SPLITS,
    STARTS,
    STAY,
    UP,
)
from ..messenger.render import legend, render_ascii
from .args import nonnegative_int, positive_int

KEY_ACTIONS: dict[str, int] = {
    "up": UP,
    "w": UP,
    "down": DOWN,
    "s": DOWN,
    "left": LEFT,
    "a": LEFT,
    "right": RIGHT,
    "d": RIGHT,
    " ": STAY,
    ".": STAY,
    "x": STAY,
}
"""Key name -> action. Arrow keys are named "up", "down", "left", "right" by the key readers."""
QUIT_KEYS = frozenset({"q", "\x03", "\x04"})  # q, Ctrl-C and Ctrl-D as raw characters
IGNORED_KEYS = frozenset({"\n", "\r"})
KEY_HELP = "keys: arrows or w/a/s/d move, space . x stay, q quits"

_ARROWS = {"A": "up", "B": "down", "C": "right", "D": "left"}
_CLEAR_SCREEN = "\x1b[H\x1b[2J"

KeyReader = Callable[[], "str | None"]
"""Returns the next key (a character, or an arrow's name), or None when the input has ended."""
Writer = Callable[[str], Any]


# --------------------------------------------------------------------------- keys
def split_keys(text: str) -> list[str]:
    """Characters of `text` as keys, with ANSI arrow sequences (ESC [ A, ESC O A, ...) as one key
    each, so that a pasted or recorded terminal session replays the same moves."""
    keys: list[str] = []
    i = 0
    while i < len(text):
        if text[i] == "\x1b" and i + 2 < len(text) and text[i + 1] in "[O" and text[i + 2] in _ARROWS:
            keys.append(_ARROWS[text[i + 2]])
            i += 3
        else:
            keys.append(text[i])
            i += 1
    return keys


def line_key_reader(stream: IO[str]) -> KeyReader:
    """A key reader over a text stream read line by line (pipes, files, tests)."""

    def keys() -> Iterator[str]:
        for line in stream:
            yield from split_keys(line)

    it = keys()
    return lambda: next(it, None)


@contextlib.contextmanager
def tty_key_reader(fd: int) -> Iterator[KeyReader]:
    """Single keys from a terminal, without waiting for Enter.

    cbreak mode (not raw) keeps Ctrl-C as a signal and keeps newline output translation, so the
    board prints normally; the previous terminal settings come back in `finally`, whatever ends
    the game (q, end of game, Ctrl-C, an exception).
    """
    import termios
    import tty

    saved = termios.tcgetattr(fd)

    def more_bytes() -> bool:
        return bool(select.select([fd], [], [], 0.05)[0])

    def read_key() -> str | None:
        byte = os.read(fd, 1)
        if not byte:
            return None
        if byte == b"\x1b" and more_bytes():
            rest = os.read(fd, 2)
            if len(rest) == 2 and rest[:1] in (b"[", b"O") and rest[1:].decode(errors="replace") in _ARROWS:
                return _ARROWS[rest[1:].decode()]
            return "\x1b"
        if byte[0] >= 0x80:  # a multi-byte UTF-8 character: read the rest so it is one key
            while more_bytes():
                byte += os.read(fd, 1)
                with contextlib.suppress(UnicodeDecodeError):
                    return byte.decode()
        return byte.decode(errors="replace")

    try:
        tty.setcbreak(fd)
        yield read_key
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


# --------------------------------------------------------------------------- the game
def _screen(obs: Any, manual: list[str], status: str, color: bool, title: str) -> str:
    lines = [title] if title else []
    lines.append("Manual:")
    lines += [f"  {i + 1}. {text}" for i, text in enumerate(manual)]
    lines.append(render_ascii(obs, color=color))
    lines.append(legend(obs))
    lines.append(status)
    return "\n".join(lines) + "\n"


def _key_name(key: str) -> str:
    return key if len(key) > 1 else repr(key)


def run_game(
    env: Any,
    seed: int,
    start: int | None,
    read_key: KeyReader,
    write: Writer,
    *,
    color: bool = False,
    clear: bool = False,
    title: str = "",
) -> int:
    """Play one episode of `env` (a MessengerEnv) with keys from `read_key`, writing to `write`.

    Taking the key reader and the writer as arguments keeps the game loop free of terminal
    handling, so tests and scripts drive it with plain strings. Unknown keys do not spend a step;
    they print a hint. Returns 0 when the episode ends, on q and when the input ends.
    """
    obs, info = env.reset(seed=seed, options={"start": start})
    manual = list(info["manual"])
    total = 0.0
    last: float | None = None
    note = ""
    while True:
        steps = f"step {env.t}/{env.max_steps}"
        reward = "-" if last is None else f"{last:+g}"
        status = f"{steps}   last reward {reward}   return {total:+g}\n{KEY_HELP}"
        if note:
            status += "\n" + note
        write((_CLEAR_SCREEN if clear else "") + _screen(obs, manual, status, color, title))
        note = ""

        key = read_key()
        while key is not None and key in IGNORED_KEYS:
            key = read_key()
        if key is None:
            write(f"input ended: quitting after {env.t} steps, return {total:+g}\n")
            return 0
        if key.lower() in QUIT_KEYS:
            write(f"quit after {env.t} steps, return {total:+g}\n")
            return 0
        action = KEY_ACTIONS.get(key.lower() if len(key) == 1 else key)
        if action is None:
            note = f"unknown key {_key_name(key)} ignored; {KEY_HELP}"
            continue

        obs, last, terminated, truncated, info = env.step(action)
        total += last
        note = f"you pressed {_key_name(key)}: {ACTION_NAMES[action]}"
        if terminated or truncated:
            if env.won:
                outcome = "You won: the message reached the goal!"
            elif not env.alive:
                outcome = "You died."
            else:
                outcome = f"Time limit: {env.max_steps} steps are up."
            status = f"step {env.t}/{env.max_steps}   last reward {last:+g}   return {total:+g}\n{outcome}"
            write((_CLEAR_SCREEN if clear else "") + _screen(obs, manual, status, color, title))
            write(f"The game was: {env.spec}\n")
            return 0


# --------------------------------------------------------------------------- command line
def _start_arg(text: str) -> int | None:
    """--start: a start index 0..23, or 'none' for the one the seed picks."""
    if text.lower() == "none":
        return None
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 0-{len(STARTS) - 1} or 'none', got {text!r}") from None
    if not 0 <= value < len(STARTS):
        raise argparse.ArgumentTypeError(f"expected 0-{len(STARTS) - 1} or 'none', got {value}")
    return value


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "play",
        help="play a Messenger game in the terminal",
        description="Play a Messenger game in the terminal. " + KEY_HELP + ".",
        epilog="When stdin is not a terminal, every character of every input line is one key.",
    )
    p.add_argument("--split", choices=SPLITS, default="newall-test", metavar="SPLIT", help="split the game comes from")
    p.add_argument("--index", type=nonnegative_int, default=0, help="index of the game in the split")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="episode seed: moves, channel order, manual")
    p.add_argument(
        "--start",
        type=_start_arg,
        default=None,
        metavar="{0-23,none}",
        help="start positions (index into the 24 starts); 'none' (default) lets the seed choose",
    )
    p.add_argument("--max-steps", type=positive_int, default=DEFAULT_MAX_STEPS, help="time limit in actions")
    p.add_argument(
        "--texts",
        type=Path,
        nargs="*",
        default=None,
        metavar="PATH",
        help="human-written description JSON file(s) to draw the manual from (default: generated)",
    )
    p.add_argument("--no-color", action="store_true", help="no ANSI colours even on a terminal")
    p.set_defaults(func=run)


def _pools(texts: list[Path] | None) -> Any:
    from ..text import DescriptionPools

    if texts:
        return DescriptionPools.from_files([str(p) for p in texts])
    return DescriptionPools.generated()


def run(opts: argparse.Namespace) -> int:
    """`lwm play`: 0 when the game was played or quit, 130 on Ctrl-C; bad input raises LwmError."""
    from ..data.splits import load_split
    from ..messenger.env import MessengerEnv

    games = load_split(opts.split)
    if not 0 <= opts.index < len(games):
        raise LwmError(f"--index must be in 0..{len(games) - 1} for {opts.split}, got {opts.index}")
    pools = _pools(opts.texts)
    env = MessengerEnv(games[opts.index], pools=pools, split=opts.split, max_steps=opts.max_steps)
    title = f"Messenger: {opts.split} game {opts.index}, seed {opts.seed}"
    interactive = sys.stdin.isatty()

    def write(text: str) -> None:
        sys.stdout.write(text)
        sys.stdout.flush()

    try:
        if interactive:
            color = sys.stdout.isatty() and not opts.no_color and os.environ.get("NO_COLOR") is None
            with tty_key_reader(sys.stdin.fileno()) as read_key:
                return run_game(
                    env, opts.seed, opts.start, read_key, write, color=color, clear=sys.stdout.isatty(), title=title
                )
        return run_game(env, opts.seed, opts.start, line_key_reader(sys.stdin), write, title=title)
    except KeyboardInterrupt:
        # Ctrl-C leaves the cursor after the board's last line; end it so the shell prompt is clean.
        print("\ninterrupted", file=sys.stderr)
        return 130


def play_main(args: list[str] | None = None) -> int:
    """`lwm play ARGS` as a function (for tests and scripts); returns the exit status."""
    from .main import main

    return main(["play", *(sys.argv[1:] if args is None else args)])


if __name__ == "__main__":
    sys.exit(play_main())
