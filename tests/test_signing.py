"""Reviewer signatures (lwm_models.signing): who may approve, correct, label and change the manual."""

from __future__ import annotations

import json
import os
import stat

import pytest

from lwm_models import messages, signing

ALICE = bytes(range(32))
BOB = bytes(range(32, 64))
APPROVE = {"version": 2, "review_id": "newall-test:0:0", "plan_id": 3, "decision": "approve"}


def test_a_signed_payload_verifies_as_its_reviewer_after_the_wire():
    signed = signing.sign("review_feedback", APPROVE, "alice", ALICE)
    assert signed["reviewer"] == "alice" and len(signed["signature"]) == 64
    received = messages.parse("review_feedback", messages.dump("review_feedback", signed))
    assert signing.Keyring({"alice": ALICE, "bob": BOB}).verify("review_feedback", received) == "alice"


def test_the_canonical_form_ignores_key_order_and_whitespace():
    signed = signing.sign("review_feedback", APPROVE, "alice", ALICE)
    shuffled = json.loads(json.dumps(dict(reversed(list(signed.items()))), indent=3))
    assert list(shuffled) != list(signed)
    assert signing.signed_bytes("review_feedback", shuffled) == signing.signed_bytes("review_feedback", signed)
    assert signing.Keyring({"alice": ALICE}).verify("review_feedback", shuffled) == "alice"


@pytest.mark.parametrize(
    "change",
    [
        {"plan_id": 4},  # the approval moved to another plan
        {"review_id": "newall-test:0:1"},  # ... or to another review
        {"decision": "abort"},
        {"reviewer": "bob"},  # alice's signature passed off as bob's
        {"signature": "0" * 64},
    ],
    ids=["plan", "review", "decision", "reviewer", "signature"],
)
def test_an_altered_or_forged_payload_is_refused(change):
    signed = {**signing.sign("review_feedback", APPROVE, "alice", ALICE), **change}
    with pytest.raises(signing.BadSignature, match="bad signature"):
        signing.Keyring({"alice": ALICE, "bob": BOB}).verify("review_feedback", signed)


def test_a_signature_made_with_another_key_is_refused():
    signed = signing.sign("review_feedback", APPROVE, "alice", BOB)
    with pytest.raises(signing.BadSignature, match=r"/review/feedback: review_feedback from reviewer 'alice'"):
        signing.Keyring({"alice": ALICE}).verify("review_feedback", signed, "/review/feedback")


def test_a_signature_holds_for_its_kind_only():
    labels = {"version": 2, "review_id": "r", "request_id": 1, "states": [0], "actions": [3]}
    signed = signing.sign("labels", labels, "alice", ALICE)
    with pytest.raises(signing.BadSignature):
        signing.Keyring({"alice": ALICE}).verify("other_kind", signed)


def test_an_untrusted_reviewer_is_refused_even_with_a_valid_signature():
    signed = signing.sign("manual", {"version": 2, "descriptions": ["a", "b", "c"]}, "mallory", BOB)
    keyring = signing.Keyring({"alice": ALICE, "mallory": BOB})
    assert keyring.verify("manual", signed) == "mallory"
    with pytest.raises(signing.UntrustedReviewer, match=r"reviewer 'mallory', who is not trusted \(trusted: alice\)"):
        keyring.only(["alice"]).verify("manual", signed, "/feedback/manual")
    with pytest.raises(signing.UntrustedReviewer, match="trusted: no one"):
        signing.Keyring({}).verify("manual", signed)
    with pytest.raises(signing.KeyFileError, match="'carol' has no key"):
        keyring.only(["carol"])


def test_unsigned_feedback_is_refused():
    keyring = signing.Keyring({"alice": ALICE})
    with pytest.raises(signing.UnsignedPayload, match="unsigned review_feedback"):
        keyring.verify("review_feedback", {**APPROVE, "reviewer": "alice"})
    signed = signing.sign("review_feedback", APPROVE, "alice", ALICE)
    del signed["reviewer"]
    with pytest.raises(signing.UnsignedPayload, match="names no reviewer"):
        keyring.verify("review_feedback", signed)
    with pytest.raises(signing.SigningError, match="reviewer id"):
        signing.sign("review_feedback", APPROVE, "no spaces please", ALICE)


def test_the_key_file_is_created_private_and_then_reused(tmp_path):
    path = tmp_path / "state" / "reviewer_keys.json"
    keys = signing.ensure_key_file(path)
    assert set(keys) == {"scripted", "terminal"} and all(len(k) == signing.KEY_BYTES for k in keys.values())
    assert keys["scripted"] != keys["terminal"]
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    text = path.read_text()
    assert signing.ensure_key_file(path) == keys and path.read_text() == text  # reused as it is
    assert signing.load_keys(path) == keys
    # A reviewer it lacks is added; the others keep their keys, the file stays private.
    more = signing.ensure_key_file(path, ["alice", "scripted"])
    assert set(more) == {"scripted", "terminal", "alice"} and more["scripted"] == keys["scripted"]
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert [p.name for p in path.parent.iterdir()] == ["reviewer_keys.json"]  # no temporary file left


def test_a_key_file_others_can_read_or_a_malformed_one_is_refused(tmp_path):
    path = tmp_path / "keys.json"
    signing.ensure_key_file(path)
    os.chmod(path, 0o644)
    with pytest.raises(signing.KeyFileError, match="chmod 600"):
        signing.load_keys(path)
    with pytest.raises(signing.KeyFileError, match="no such key file"):
        signing.load_keys(tmp_path / "missing.json")
    for bad, why in [
        ("{nope", "not JSON"),
        ('{"format": "lwm-reviewer-keys", "version": 1, "keys": {"alice": "abcd"}}', "32 bytes"),
        ('{"format": "lwm-reviewer-keys", "version": 1, "keys": {"a b": "00"}}', "an id and 64 hex digits"),
        ('{"keys": {}}', "not a key file"),
    ]:
        path.write_text(bad)
        os.chmod(path, 0o600)
        with pytest.raises(signing.KeyFileError, match=why):
            signing.load_keys(path)


def test_a_reviewer_added_to_the_key_file_later_is_trusted_without_a_restart(tmp_path):
    """A person who joins a running system (the page's "who is reviewing?") gets a key in the file;
    the planner's keyring, read at its start, reads the file again when it first sees them."""
    path = tmp_path / "keys.json"
    signing.ensure_key_file(path)
    keyring = signing.Keyring(signing.load_keys(path), str(path), path)
    restricted = keyring.only(["terminal"])
    bob = signing.ensure_key_file(path, ["bob"])["bob"]
    payload = signing.sign("review_feedback", APPROVE, "bob", bob)
    assert keyring.verify("review_feedback", payload) == "bob"
    with pytest.raises(signing.UntrustedReviewer, match="'bob', who is not trusted"):
        restricted.verify("review_feedback", payload)  # a fixed list of trusted reviewers stays fixed
    # A key removed from the file is dropped at the next reread; an unchanged file is not read again.
    keys = signing.load_keys(path)
    del keys["bob"]
    signing._write(path, keys, replace=True)
    carol = signing.ensure_key_file(path, ["carol"])["carol"]
    assert keyring.verify("review_feedback", signing.sign("review_feedback", APPROVE, "carol", carol)) == "carol"
    with pytest.raises(signing.UntrustedReviewer):
        keyring.verify("review_feedback", payload)


def test_a_keyring_without_its_file_trusts_the_file_once_it_is_made(tmp_path):
    path = tmp_path / "keys.json"
    keyring = signing.Keyring({}, f"{path} (missing)", path)
    key = signing.ensure_key_file(path, ["alice"])["alice"]
    assert keyring.verify("review_feedback", signing.sign("review_feedback", APPROVE, "alice", key)) == "alice"
