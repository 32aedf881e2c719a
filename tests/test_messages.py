"""The JSON payloads: every schema is valid, versioned and carries an example that validates."""

from __future__ import annotations

import copy
import json

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from lwm_models import messages, signing

KINDS = messages.kinds()


def test_every_payload_of_the_system_has_a_schema():
    assert set(KINDS) == {
        "ack",
        "env_reset_request",
        "env_response",
        "env_step_request",
        "error",
        "execution_report",
        "history_request",
        "history_response",
        "imagine_request",
        "imagine_response",
        "label_request",
        "labels",
        "manual",
        "plan",
        "progress",
        "review_feedback",
        "state",
        "status",
    }


@pytest.mark.parametrize("kind", KINDS)
def test_schema_is_versioned_and_its_examples_validate(kind):
    schema = json.loads((messages.SCHEMA_DIR / f"{kind}.schema.json").read_text())
    assert "version" in schema["required"] and schema["properties"]["version"]["const"] == messages.version(kind)
    assert messages.version(kind) >= messages.VERSION
    assert schema["examples"], "docs/ros.md points readers to the schema's example"
    for example in schema["examples"]:
        assert messages.parse(kind, json.dumps(example)) == example
        wrong = copy.deepcopy(example)
        wrong["version"] = messages.version(kind) + 1
        with pytest.raises(messages.MessageError, match="version"):
            messages.validate(kind, wrong)


SIGNED = {"review_feedback": 2, "labels": 2, "manual": 2}  # version 2 added the reviewer's signature


def test_feedback_kinds_carry_a_signature_and_their_examples_are_really_signed():
    """The examples' signatures are made with the documented example key (its seed 32 zero
    bytes), each verified at the time it says it was signed."""
    public = Ed25519PrivateKey.from_private_bytes(bytes(32)).public_key()
    for kind in KINDS:
        props = messages.schema(kind)["properties"]
        assert ("signature" in props) == (kind in SIGNED), kind
        assert messages.version(kind) == SIGNED.get(kind, 1), kind
    for kind in SIGNED:
        examples = messages.schema(kind)["examples"]
        signed = [e for e in examples if "signature" in e]
        assert signed, f"{kind}: no signed example"
        for example in signed:
            keyring = signing.Keyring({"scripted": public, "terminal": public})
            assert keyring.verify(kind, example, now=example["signed_at"]) == example["reviewer"]
    # The environment's manual (/env/manual) is not signed: the environment node is trusted.
    assert any(e.get("source") == "env" and "signature" not in e for e in messages.schema("manual")["examples"])


@pytest.mark.parametrize(
    "text, why",
    [
        ('{"version": 1, "n": NaN}', "NaN is not a number"),
        ('{"version": 1, "temperature": Infinity}', "Infinity is not a number"),
        ("[" * 100000 + "]" * 100000, "recursion"),
        ("{not json", "Expecting property name"),
    ],
)
def test_text_that_is_not_plain_json_is_refused_with_the_reason(text, why):
    with pytest.raises(messages.MessageError, match=why):
        messages.parse("imagine_request", text)


def test_parse_and_dump_errors_name_the_problem():
    with pytest.raises(messages.MessageError, match="not JSON"):
        messages.parse("manual", "{nope")
    with pytest.raises(messages.MessageError, match="descriptions"):
        messages.parse("manual", '{"version": 2, "descriptions": ["only one"]}')
    with pytest.raises(messages.MessageError, match="no schema"):
        messages.validate("telemetry", {})
    text = messages.dump("review_feedback", {"review_id": "r", "plan_id": 1, "decision": "approve"})
    assert json.loads(text)["version"] == 2
    with pytest.raises(messages.MessageError, match="decision"):
        messages.dump("review_feedback", {"review_id": "r", "plan_id": 1, "decision": "maybe"})


def test_real_states_must_be_game_states_and_imagined_ones_need_not():
    """A state or an imagination start that no game can be in is refused with the reason; a plan
    may show an impossible imagined state (the world model imagined it; the reviewer should see it)."""
    state = copy.deepcopy(messages.schema("state")["examples"][0])
    messages.validate("state", state)
    entity = state["observation"][0]
    state["observation"][1] = list(entity)  # the same entity twice
    with pytest.raises(messages.MessageError, match="state: observation: the entity channels repeat an id"):
        messages.parse("state", json.dumps(state))
    request = {"version": 1, "observations": [state["observation"]], "n": 1}
    with pytest.raises(messages.MessageError, match="observations/0: the entity channels repeat"):
        messages.validate("imagine_request", request)
    request["observations"][0][3] = [4, 1, 1]  # an entity id in the avatar channel
    request["observations"][0][1] = [0, 0, 0]
    with pytest.raises(messages.MessageError, match="avatar channel holds id 4"):
        messages.validate("imagine_request", request)
    plan = copy.deepcopy(messages.schema("plan")["examples"][0])
    plan["observations"][-1][0] = list(plan["observations"][-1][1])  # an entity imagined twice
    messages.validate("plan", plan)


FEEDBACK = {"version": 2, "review_id": "newall-test:0:0", "plan_id": 1}
MANUAL_V = messages.version("manual")
LABELS = {"version": messages.version("labels"), "review_id": "newall-test:0:0", "request_id": 1}


@pytest.mark.parametrize(
    ("kind", "payload", "said"),
    [
        ("review_feedback", {**FEEDBACK, "decision": "approve", "plan_id": 0}, "the plan number must be at least 1"),
        ("review_feedback", {**FEEDBACK, "decision": "yes"}, "the decision must be one of 'approve', 'reject'"),
        ("review_feedback", {**FEEDBACK, "decision": "corrections"}, "'corrections' is missing"),
        (
            "review_feedback",
            {**FEEDBACK, "decision": "corrections", "corrections": [{"step": 1, "action": 7}]},
            "correction 1: an action is 0 up, 1 down, 2 left, 3 right or 4 stay",
        ),
        (
            "review_feedback",
            {**FEEDBACK, "decision": "corrections", "corrections": [{"step": 0, "action": 1}]},
            "correction 1: steps are counted from 1",
        ),
        ("review_feedback", {**FEEDBACK, "decision": "approve", "mood": 1}, "'mood' is not something this message"),
        ("review_feedback", {**FEEDBACK, "decision": "approve", "version": 1}, "another version of the system"),
        ("manual", {"version": MANUAL_V, "descriptions": ["one"]}, "the manual needs 3 descriptions"),
        ("manual", {"version": MANUAL_V, "descriptions": ["a", "b", "c", "d"]}, "the manual takes 3 descriptions"),
        ("manual", {"version": MANUAL_V, "descriptions": ["a", "  ", "c"]}, "description 2 is empty"),
        ("manual", {"version": MANUAL_V, "descriptions": ["a", "", "c"]}, "description 2 is empty"),
        ("manual", {"version": MANUAL_V, "descriptions": ["a", "b", 3]}, "description 3 must be text"),
        (
            "manual",
            {
                "version": MANUAL_V,
                "descriptions": ["a", "b", "c"],
                "facts": [{"entity": "dragon", "field": "role", "value": "enemy"}],
            },
            "fact 1: its entity is one of",
        ),  # fmt: skip
        (
            "manual",
            {"version": MANUAL_V, "descriptions": ["a", "b", "c"], "facts": [{"entity": "dog"}]},
            "fact 1 needs an entity, a field and a value",
        ),
        ("manual", {"version": MANUAL_V, "descriptions": ["a", "b", "c" * 3000]}, "description 3 is over 2000"),
        ("labels", {**LABELS, "states": [0], "actions": [9]}, "label 1: an action is 0 up, 1 down"),
        ("labels", {**LABELS, "states": "0", "actions": [1]}, "the labelled states must be a list"),
        ("labels", {**LABELS, "states": [0]}, "'actions' is missing"),
        # Fields no rewording names: their place in words, items counted from 1.
        ("labels", {**LABELS, "states": [-1], "actions": [3]}, "the labelled states, item 1: must be at least 0"),
        ("labels", {**LABELS, "states": [0, 1], "actions": [3, "x"]}, "the actions, item 2: must be a whole number"),
        (
            "review_feedback",
            {**FEEDBACK, "decision": "corrections", "corrections": [{"step": 1, "action": "up"}]},
            "the corrections, item 1, action: must be a whole number",
        ),
        (
            "review_feedback",
            {**FEEDBACK, "decision": "corrections", "corrections": [{"step": 1}, {"step": 2}]},
            "the corrections, item 1: needs 'action'",
        ),
    ],
)
def test_every_refusal_a_person_can_cause_is_said_in_plain_words(kind, payload, said):
    with pytest.raises(messages.MessageError) as refused:
        messages.validate(kind, payload)
    reason = messages.plain_reason(refused.value)
    assert said in reason, reason
    assert reason.startswith({"review_feedback": "the answer", "manual": "the manual", "labels": "the labels"}[kind])
    for jargon in ("must match pattern", "properties", "const definition", "(top level)", "Error"):
        assert jargon not in reason, reason


@pytest.mark.parametrize(
    ("text", "said"),
    [("{not json", "it is not JSON (check the quotes and brackets)"), ("[1, 2]", "it is not a JSON object")],
)
def test_text_that_is_no_message_is_refused_in_plain_words(text, said):
    with pytest.raises(messages.MessageError) as refused:
        messages.parse("manual", text)
    assert messages.plain_reason(refused.value) == f"the manual was refused: {said}"


def test_the_systems_own_refusals_keep_their_words_and_a_crash_is_named():
    from lwm_models.agent.agent import FeedbackError

    assert messages.plain_reason(FeedbackError("step 99 is not in the plan (steps 1..12)")) == (
        "step 99 is not in the plan (steps 1..12)"
    )
    assert messages.plain_reason(KeyError("x")).startswith("it could not be taken (KeyError")
    assert messages.msg_id_of('{"msg_id": "page-1", "x": [}') is None
    assert messages.msg_id_of('{"msg_id": "page-1"}') == "page-1"
