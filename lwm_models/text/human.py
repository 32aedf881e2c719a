"""Loader of human-written Messenger description files.

Format: a JSON object identity -> role (enemy | message | goal) -> movement (chaser | fleeing |
immovable | unknown) -> list of strings. "unknown" entries (the text gives no movement) are not
used by the benchmark and are skipped. Empty lists are allowed; a file with no usable description
at all is an error.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable

from ..errors import TextFileError
from ..messenger.constants import IDENTITIES, MOVEMENTS, ROLES, Triple


def load_description_file(path: str | Path) -> dict[Triple, list[str]]:
    path = Path(path)
    if not path.is_file():
        raise TextFileError(f"{path}: no such description file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise TextFileError(f"{path}: not a JSON file ({exc})") from None
    if not isinstance(data, dict):
        raise TextFileError(f"{path}: the top level must be an object identity -> role -> movement -> list")
    out: dict[Triple, list[str]] = {}
    for ident, roles in data.items():
        if ident not in IDENTITIES:
            raise TextFileError(f"{path}: unknown identity {ident!r}; known: {sorted(IDENTITIES)}")
        if not isinstance(roles, dict):
            raise TextFileError(f"{path}: {ident} must map roles to objects")
        for role, movements in roles.items():
            if role not in ROLES:
                raise TextFileError(f"{path}: unknown role {role!r} at {ident}; known: {list(ROLES)}")
            if not isinstance(movements, dict):
                raise TextFileError(f"{path}: {ident}.{role} must map movements to lists")
            for mov, texts in movements.items():
                where = f"{ident}.{role}.{mov}"
                if mov not in (*MOVEMENTS, "unknown"):
                    raise TextFileError(f"{path}: unknown movement {mov!r} at {ident}.{role}")
                if not isinstance(texts, list):
                    raise TextFileError(f"{path}: {where} must be a list of strings")
                for k, text in enumerate(texts):
                    if not isinstance(text, str) or not text.strip():
                        raise TextFileError(f"{path}: {where}[{k}] must be a non-empty string")
                if mov != "unknown" and texts:
                    out.setdefault((ident, mov, role), []).extend(t.strip() for t in texts)
    if not out:
        raise TextFileError(f"{path}: holds no usable description")
    return out


def load_description_files(paths: Iterable[str | Path]) -> dict[Triple, list[str]]:
    """Several files merged; each text kept once (first occurrence), in file order."""
    merged: dict[Triple, dict[str, None]] = {}
    for path in paths:
        for triple, texts in load_description_file(path).items():
            merged.setdefault(triple, {}).update(dict.fromkeys(texts))
    return {t: list(texts) for t, texts in merged.items()}
