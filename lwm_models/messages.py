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


def msg_id_of(text: str) -> str | None:
    """The sender's msg_id of a payload, read before (and whether or not) it validates, so that
    a refusal can be answered to its sender; None when there is none to read."""
    try:
        value = json.loads(text).get("msg_id")
    except (ValueError, TypeError, AttributeError, RecursionError):
        return None
    return value if isinstance(value, str) and 0 < len(value) <= 64 else None


KIND_NAMES = {
    "review_feedback": "the answer to the plan was refused",
    "labels": "the labels were refused",
    "manual": "the manual was refused",
}
TYPE_NAMES = {
    "integer": "a whole number",
    "array": "a list",
    "string": "text",
    "object": "a JSON object",
    "boolean": "true or false",
    "number": "a number",
}
FIELD_NAMES = {
    "plan_id": "the plan number",
    "review_id": "the review",
    "decision": "the decision",
    "descriptions": "the manual",
    "corrections": "the corrections",
    "states": "the labelled states",
    "actions": "the actions",
    "rounds": "the number of rounds",
    "request_id": "the label request",
    "signature": "the signature",
    "reviewer": "the reviewer's name",
    "msg_id": "the message id",
    "source": "the manual's source",
}
# A schema's complaint, as a person would say it: (pattern, reworded). \1 etc. are the pattern's groups.
PLAIN = [
    (r"^descriptions: must contain at least (\d+) items$", r"the manual needs \1 descriptions, one per entity"),
    (r"^descriptions: must contain less than or equal to (\d+) items$", r"the manual takes \1 descriptions, no more"),
    (r"^descriptions/(\d+): must match pattern .*$", "description {n1} is empty"),
    (r"^descriptions/(\d+): must be longer than or equal to 1 characters$", "description {n1} is empty"),
    (r"^descriptions/(\d+): must be string$", "description {n1} must be text"),
    (r"^facts/(\d+)/(\w+): must be one of \[(.*)\]$", r"fact {n1}: its \2 is one of \3"),
    (r"^facts/(\d+): must contain \[(.*)\] properties$", r"fact {n1} needs an entity, a field and a value"),
    (
        r"^descriptions/(\d+): must be shorter than or equal to (\d+) characters$",
        r"description {n1} is over \2 characters",
    ),
    (
        r"^corrections/(\d+)/action: must be (?:smaller|bigger) than or equal to \d+$",
        "correction {n1}: an action is 0 up, 1 down, 2 left, 3 right or 4 stay",
    ),
    (r"^corrections/(\d+)/step: must be bigger than or equal to 1$", "correction {n1}: steps are counted from 1"),
    (
        r"^actions/(\d+): must be (?:smaller|bigger) than or equal to \d+$",
        "label {n1}: an action is 0 up, 1 down, 2 left, 3 right or 4 stay",
    ),
    (r"^\(top level\): must contain \['(\w+)'\] properties$", r"'\1' is missing"),
    (r"^\(top level\): must not contain \{'(\w+)'\} properties$", r"'\1' is not something this message can carry"),
    (r"^\(top level\): must be object$", "it is not a JSON object"),
    (
        r"^version: must be same as const definition: (\d+)$",
        r"it is written for another version of the system (expected version \1)",
    ),
    (r"^decision: must be one of \[(.*)\]$", r"the decision must be one of \1"),
    (r"^(\w+): must be bigger than or equal to (\S+)$", r"{field1} must be at least \2"),
    (r"^(\w+): must be smaller than or equal to (\S+)$", r"{field1} must be at most \2"),
    (r"^(\w+): must be (integer|array|string|object|boolean|number)$", "{field1} must be {type2}"),
    (r"^(\w+): must match pattern .*$", "{field1} is empty or has characters it cannot have"),
    (r"^not JSON: .*$", "it is not JSON (check the quotes and brackets)"),
]


# What a schema says of a field, in words, for fields PLAIN does not name.
COMPLAINTS = [
    (r"^must be (integer|array|string|object|boolean|number)$", "must be {type1}"),
    (r"^must be bigger than or equal to (\S+)$", r"must be at least \1"),
    (r"^must be smaller than or equal to (\S+)$", r"must be at most \1"),
    (r"^must match pattern .*$", "is empty or has characters it cannot have"),
    (r"^must be one of \[(.*)\]$", r"must be one of \1"),
    (r"^must contain \[(.*)\] properties$", r"needs \1"),
    (r"^must contain at least (\d+) items$", r"needs at least \1"),
    (r"^must contain less than or equal to (\d+) items$", r"takes at most \1"),
]


def plain_reason(exc: BaseException) -> str:
    """Why a payload was refused, in words a person at the page or the terminal understands: a
    schema's complaint is reworded (PLAIN), any other refusal keeps its own message, which the
    nodes already write for people."""
    import re

    text = str(exc)
    if not isinstance(exc, MessageError):
        if isinstance(exc, (LwmError, ValueError)):  # the system's own refusals are written for people
            return text
        return f"it could not be taken ({type(exc).__name__}: {text})"
    kind, _, rest = text.partition(": ")
    what = KIND_NAMES.get(kind, f"the {kind.replace('_', ' ')} was refused")
    for pattern, reworded in PLAIN:
        m = re.match(pattern, rest)
        if m:
            groups = m.groups()
            fill = {}
            for i, g in enumerate(groups, 1):
                if g is not None and g.isdigit():
                    fill[f"n{i}"] = int(g) + 1  # people count from 1
                fill[f"field{i}"] = FIELD_NAMES.get(g, g) if g is not None else ""
                fill[f"type{i}"] = TYPE_NAMES.get(g, g) if g is not None else ""
            said = m.expand(reworded).format(**fill)
            return f"{what}: {said}"
    path, colon, complaint = rest.partition(": ")
    if colon and re.fullmatch(r"[\w/]+", path):  # any other field: its place in words, items counted from 1
        where = ", ".join(f"item {int(p) + 1}" if p.isdigit() else FIELD_NAMES.get(p, p.replace("_", " "))
                          for p in path.split("/"))  # fmt: skip
        for pattern, reworded in COMPLAINTS:
            complaint = re.sub(pattern, lambda m, r=reworded: m.expand(r).format(type1=TYPE_NAMES.get(m[1], m[1])),
                               complaint)  # fmt: skip
        return f"{what}: {where}: {complaint}"
    return f"{what}: {rest}"
