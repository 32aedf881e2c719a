"""The JSON payloads the system exchanges, validated against the schemas in msgs_json/.

The core owns the schemas' meaning (what a state, manual or imagine request is); the ROS nodes
only carry the strings. Every node validates what it receives and what it sends.
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

import fastjsonschema
from jsonschema import Draft202012Validator

from .errors import LwmError
from .messenger.observation import InvalidObservation, check_observation

SCHEMA_DIR = Path(__file__).resolve().parent.parent / "msgs_json"
VERSION = 1  # the first version of every kind; a kind whose format changed has a higher one (`version`)


class MessageError(LwmError, ValueError):
    """A payload that is not JSON or does not match its schema."""


@cache
def schema(kind: str) -> dict:
    path = SCHEMA_DIR / f"{kind}.schema.json"
    if not path.is_file():
        raise MessageError(f"no schema for message kind {kind!r} in {SCHEMA_DIR}")
    loaded = json.loads(path.read_text())
    Draft202012Validator.check_schema(loaded)
    return loaded


@cache
def validator(kind: str):
    """The schema compiled to Python (fastjsonschema). The schemas use no keyword newer than
    draft 7, so the draft-7 compiler reads them as written."""
    compiled = {k: v for k, v in schema(kind).items() if k not in ("$schema", "examples")}
    return fastjsonschema.compile({**compiled, "$schema": "http://json-schema.org/draft-07/schema#"})


def version(kind: str) -> int:
    """The version a payload of this kind must carry: the schema's `version` constant. Kinds are
    versioned one by one, so a change to one format does not touch the others' senders."""
    return schema(kind)["properties"]["version"]["const"]


def kinds() -> list[str]:
    return sorted(p.name.removesuffix(".schema.json") for p in SCHEMA_DIR.glob("*.schema.json"))


REAL_STATES = {"state": ("observation",), "imagine_request": ("observation", "observations")}
"""Where a kind carries observations that claim to be real game states (checked for meaning, not
only shape). Imagined observations (plans, responses, label requests) are not: a world model may
imagine the impossible, and a reviewer should see it."""


def validate(kind: str, payload: Any) -> dict:
    """Return the payload if it matches its schema and its real states are game states; else raise
    MessageError naming the first problem."""
    try:
        validator(kind)(payload)
    except fastjsonschema.JsonSchemaValueException as e:
        where = "/".join(str(p) for p in (e.path or [])[1:]) or "(top level)"
        message = e.message.removeprefix(e.name or "data").strip()
        raise MessageError(f"{kind}: {where}: {message}") from None
    for field in REAL_STATES.get(kind, ()):
        if field not in payload:
            continue
        one = field == "observation"
        for i, obs in enumerate([payload[field]] if one else payload[field]):
            try:
                check_observation(obs, field if one else f"{field}/{i}")
            except InvalidObservation as exc:
                raise MessageError(f"{kind}: {exc}") from None
    return payload


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number in JSON")


def decode(kind: str, text: str) -> Any:
    """A JSON string's value, or MessageError: also for NaN and Infinity, which Python's json
    reads but the schemas' number ranges do not catch, and for nesting too deep to decode."""
    try:
        return json.loads(text, parse_constant=_no_constant)
    except (ValueError, TypeError, RecursionError) as exc:  # JSONDecodeError is a ValueError
        raise MessageError(f"{kind}: not JSON: {str(exc)[:200]}") from None


def parse(kind: str, text: str) -> dict:
    """Decode and validate a JSON string."""
    return validate(kind, decode(kind, text))


def dump(kind: str, payload: dict) -> str:
    """Validate and encode a payload (fills in the version when missing)."""
    payload = {"version": version(kind), **payload}
    return json.dumps(validate(kind, payload), separators=(",", ":"))
