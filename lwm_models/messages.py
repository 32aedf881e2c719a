"""The JSON payloads the system exchanges, validated against the schemas in msgs_json/.

The core owns the schemas' meaning (what a state, manual or imagine request is); the ROS nodes
only carry the strings. Every node validates what it receives and what it sends.
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

from jsonschema import Draft202012Validator

from .errors import LwmError

SCHEMA_DIR = Path(__file__).resolve().parent.parent / "msgs_json"
VERSION = 1


class MessageError(LwmError, ValueError):
    """A payload that is not JSON or does not match its schema."""


@cache
def validator(kind: str) -> Draft202012Validator:
    path = SCHEMA_DIR / f"{kind}.schema.json"
    if not path.is_file():
        raise MessageError(f"no schema for message kind {kind!r} in {SCHEMA_DIR}")
    schema = json.loads(path.read_text())
    Draft202012Validator.check_schema(schema)
    return Draft202012Validator(schema)


def kinds() -> list[str]:
    return sorted(p.name.removesuffix(".schema.json") for p in SCHEMA_DIR.glob("*.schema.json"))


def validate(kind: str, payload: Any) -> dict:
    """Return the payload if it matches its schema; else raise MessageError naming the first problem."""
    errors = sorted(validator(kind).iter_errors(payload), key=lambda e: list(e.absolute_path))
    if errors:
        e = errors[0]
        where = "/".join(str(p) for p in e.absolute_path) or "(top level)"
        raise MessageError(f"{kind}: {where}: {e.message}")
    return payload


def parse(kind: str, text: str) -> dict:
    """Decode and validate a JSON string."""
    try:
        payload = json.loads(text)
    except (json.JSONDecodeError, TypeError) as exc:
        raise MessageError(f"{kind}: not JSON: {exc}") from None
    return validate(kind, payload)


def dump(kind: str, payload: dict) -> str:
    """Validate and encode a payload (fills in the version when missing)."""
    payload = {"version": VERSION, **payload}
    return json.dumps(validate(kind, payload), separators=(",", ":"))
