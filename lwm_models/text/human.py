"""Loader of human-written Messenger description files.

The original Messenger description files may not be shipped with the project (see
docs/game.md, "Descriptions"), so users pass their paths and this module reads them.

Format: a JSON object identity -> role (enemy | message | goal) -> movement (chaser | fleeing |
immovable | unknown) -> list of strings. "unknown" entries (the text gives no movement) are not
used by the benchmark and are skipped after being validated. Empty lists are allowed (the real
files have some); a file with no usable description at all is an error, because it would silently
turn a "human-written" dataset into a generated one.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

from ..errors import TextFileError
from ..messenger.constants import IDENTITIES, MOVEMENTS, ROLES, Triple

UNKNOWN_MOVEMENT = "unknown"


def _read_json(path: Path) -> object:
    if not path.exists():
        raise TextFileError(f"{path}: no such description file")
    if not path.is_file():
        raise TextFileError(f"{path}: not a file")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise TextFileError(f"{path}: not a UTF-8 text file ({exc})") from None
    except json.JSONDecodeError as exc:
        raise TextFileError(f"{path}: not valid JSON ({exc})") from None


def _expect_object(path: Path, value: object, where: str, holds: str) -> dict:
    if not isinstance(value, dict):
        got = type(value).__name__
        raise TextFileError(f"{path}: {where} must be a JSON object mapping {holds}, got {got}")
    return value


def load_description_file(path: str | Path) -> dict[Triple, list[str]]:
    """Descriptions of one file by (identity, movement, role), in file order, each kept once.

    Raises TextFileError, naming the file and the offending key path (e.g. `airplane.enemy`), for
    a missing or non-JSON file, a wrong structure, unknown names, items that are not non-empty
    strings, or a file without any usable description.
    """
    path = Path(path)
    data = _expect_object(path, _read_json(path), "the top level", "identities to roles")
    out: dict[Triple, dict[str, None]] = {}
    for ident, roles in data.items():
        if ident not in IDENTITIES:
            raise TextFileError(f"{path}: unknown identity {ident!r} at the top level; known: {sorted(IDENTITIES)}")
        roles = _expect_object(path, roles, ident, "roles to movements")
        for role, movements in roles.items():
            if role not in ROLES:
                raise TextFileError(f"{path}: unknown role {role!r} at {ident}.{role}; known: {list(ROLES)}")
            movements = _expect_object(path, movements, f"{ident}.{role}", "movements to lists")
            for mov, texts in movements.items():
                where = f"{ident}.{role}.{mov}"
                if mov not in MOVEMENTS and mov != UNKNOWN_MOVEMENT:
                    known = [*MOVEMENTS, UNKNOWN_MOVEMENT]
                    raise TextFileError(f"{path}: unknown movement {mov!r} at {where}; known: {known}")
                if not isinstance(texts, list):
                    raise TextFileError(f"{path}: {where} must be a list of descriptions, got {type(texts).__name__}")
                for k, text in enumerate(texts):
                    if not isinstance(text, str) or not text.strip():
                        raise TextFileError(f"{path}: {where}[{k}] must be a non-empty string, got {text!r}")
                if mov != UNKNOWN_MOVEMENT and texts:
                    out.setdefault((ident, mov, role), {}).update(dict.fromkeys(t.strip() for t in texts))
    if not out:
        raise TextFileError(
            f"{path}: holds no usable description (every chaser/fleeing/immovable list is empty or missing)"
        )
    return {triple: list(texts) for triple, texts in out.items()}


def load_description_files(paths: Iterable[str | Path]) -> dict[Triple, list[str]]:
    """Several files merged: each description kept once (first occurrence), in file order.

    Every file must be usable on its own (see load_description_file); no paths is an error.
    """
    paths = list(paths)
    if not paths:
        raise TextFileError("no description file given")
    merged: dict[Triple, dict[str, None]] = {}
    for path in paths:
        for triple, texts in load_description_file(path).items():
            merged.setdefault(triple, {}).update(dict.fromkeys(texts))
    return {triple: list(texts) for triple, texts in merged.items()}
