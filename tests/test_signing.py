"""Reviewer signatures (lwm_models.signing): who may approve, correct, label and change the manual.
Ed25519: a verifier holds public keys only; signatures are fresh and taken once."""

from __future__ import annotations

import json
import os
import stat

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from lwm_models import messages, signing

ALICE = Ed25519PrivateKey.from_private_bytes(bytes(range(32)))
BOB = Ed25519PrivateKey.from_private_bytes(bytes(range(32, 64)))
APPROVE = {"version": 2, "review_id": "newall-test:0:0", "plan_id": 3, "decision": "approve"}


def keyring(window: float = signing.WINDOW_S, **keys: Ed25519PrivateKey) -> signing.Keyring:
    """A verifier's keyring: the public halves only."""
    return signing.Keyring({name: key.public_key() for name, key in keys.items()}, window=window)


def test_a_signed_payload_verifies_as_its_reviewer_after_the_wire():
    signed = signing.sign("review_feedback", APPROVE, "alice", ALICE)
    assert signed["reviewer"] == "alice" and len(signed["signature"]) == 128 and len(signed["nonce"]) == 24
    received = messages.parse("review_feedback", messages.dump("review_feedback", signed))
    assert keyring(alice=ALICE, bob=BOB).verify("review_feedback", received) == "alice"


def test_the_canonical_form_ignores_key_order_and_whitespace():
    signed = signing.sign("review_feedback", APPROVE, "alice", ALICE)
    shuffled = json.loads(json.dumps(dict(reversed(list(signed.items()))), indent=3))
    assert list(shuffled) != list(signed)
    assert signing.signed_bytes("review_feedback", shuffled) == signing.signed_bytes("review_feedback", signed)
    assert keyring(alice=ALICE).verify("review_feedback", shuffled) == "alice"


@pytest.mark.parametrize(
    "change",
    [
        {"plan_id": 4},  # the approval moved to another plan
        {"review_id": "newall-test:0:1"},  # ... or to another review
        {"decision": "abort"},
        {"reviewer": "bob"},  # alice's signature passed off as bob's
        {"signed_at": 1.0},  # an old signature made to look new, or the reverse
        {"nonce": "0" * 24},  # a replay dressed up as a new message
        {"signature": "0" * 128},
        {"signature": "not hex"},
    ],
    ids=["plan", "review", "decision", "reviewer", "time", "nonce", "signature", "garbage"],
)
def test_an_altered_or_forged_payload_is_refused(change):
    signed = {**signing.sign("review_feedback", APPROVE, "alice", ALICE), **change}
    with pytest.raises(signing.BadSignature, match="bad signature"):
        keyring(alice=ALICE, bob=BOB).verify("review_feedback", signed)


def test_a_signature_made_with_another_key_is_refused():
    signed = signing.sign("review_feedback", APPROVE, "alice", BOB)
    with pytest.raises(signing.BadSignature, match=r"/review/feedback: review_feedback from reviewer 'alice'"):
        keyring(alice=ALICE).verify("review_feedback", signed, "/review/feedback")


def test_a_verifier_cannot_sign_with_what_it_holds(tmp_path):
    """What a node that checks signatures holds (the public key file) signs nothing: the file has
    no private key in it, and a key made from its bytes is another key."""
    path = tmp_path / "keys.json"
    signing.ensure_key_file(path, ["alice"])
    public = json.loads(path.read_text())["keys"]["alice"]
    assert "seed" not in path.read_text()
    forged_key = Ed25519PrivateKey.from_private_bytes(bytes.fromhex(public))
    forged = signing.sign("review_feedback", APPROVE, "alice", forged_key)
    with pytest.raises(signing.BadSignature):
        signing.Keyring(signing.load_keys(path)).verify("review_feedback", forged)
    real = signing.sign("review_feedback", APPROVE, "alice", signing.load_private_key(path, "alice"))
    assert signing.Keyring(signing.load_keys(path)).verify("review_feedback", real) == "alice"


def test_a_signature_holds_for_its_kind_only():
    labels = {"version": 2, "review_id": "r", "request_id": 1, "states": [0], "actions": [3]}
    signed = signing.sign("labels", labels, "alice", ALICE)
    with pytest.raises(signing.BadSignature):
        keyring(alice=ALICE).verify("other_kind", signed)


def test_a_replayed_payload_is_refused_and_a_stale_one_too():
    ring = keyring(window=60.0, alice=ALICE)
    signed = signing.sign("review_feedback", APPROVE, "alice", ALICE, now=1000.0)
    assert ring.verify("review_feedback", signed, now=1010.0) == "alice"
    with pytest.raises(signing.ReplayedSignature, match="taken before"):
        ring.verify("review_feedback", signed, now=1020.0)
    # Past the window it is refused as stale, whoever sends it; a new signature of the same
    # answer (a new nonce, a new time) is taken.
    with pytest.raises(signing.StaleSignature, match="signed 70 s ago; this node takes signatures of the last 60 s"):
        ring.verify("review_feedback", signed, now=1070.0)
    ahead = signing.sign("review_feedback", APPROVE, "alice", ALICE, now=2000.0)
    with pytest.raises(signing.StaleSignature, match="ahead of this host's clock"):
        ring.verify("review_feedback", ahead, now=1500.0)
    again = signing.sign("review_feedback", APPROVE, "alice", ALICE, now=1070.0)
    assert ring.verify("review_feedback", again, now=1071.0) == "alice"
    # A nonce remembered from elsewhere (the planner's ledger, after a restart) is refused too.
    fresh = keyring(window=60.0, alice=ALICE)
    fresh.remember(again["nonce"], again["signed_at"], now=1072.0)
    with pytest.raises(signing.ReplayedSignature):
        fresh.verify("review_feedback", again, now=1073.0)
    # A payload signed without time and nonce (an old sender) is refused, with the reason.
    bare = {k: v for k, v in again.items() if k not in ("signed_at", "nonce", "signature")}
    bare["signature"] = ALICE.sign(signing.signed_bytes("review_feedback", bare)).hex()
    with pytest.raises(signing.UnsignedPayload, match="no signing time and nonce"):
        fresh.verify("review_feedback", bare, now=1073.0)


def test_an_untrusted_reviewer_is_refused_even_with_a_valid_signature():
    signed = signing.sign("manual", {"version": 2, "descriptions": ["a", "b", "c"]}, "mallory", BOB)
    ring = keyring(alice=ALICE, mallory=BOB)
    assert ring.verify("manual", signed) == "mallory"
    signed = signing.sign("manual", {"version": 2, "descriptions": ["a", "b", "c"]}, "mallory", BOB)
    with pytest.raises(signing.UntrustedReviewer, match=r"reviewer 'mallory', who is not trusted \(trusted: alice\)"):
        ring.only(["alice"]).verify("manual", signed, "/feedback/manual")
    with pytest.raises(signing.UntrustedReviewer, match="trusted: no one"):
        signing.Keyring({}).verify("manual", signed)
    with pytest.raises(signing.KeyFileError, match="'carol' has no key"):
        ring.only(["carol"])


def test_unsigned_feedback_is_refused():
    ring = keyring(alice=ALICE)
    with pytest.raises(signing.UnsignedPayload, match="unsigned review_feedback"):
        ring.verify("review_feedback", {**APPROVE, "reviewer": "alice"})
    signed = signing.sign("review_feedback", APPROVE, "alice", ALICE)
    del signed["reviewer"]
    with pytest.raises(signing.UnsignedPayload, match="names no reviewer"):
        ring.verify("review_feedback", signed)
    with pytest.raises(signing.SigningError, match="reviewer id"):
        signing.sign("review_feedback", APPROVE, "no spaces please", ALICE)


def test_the_key_files_are_created_each_reviewer_its_own_private_key_and_then_reused(tmp_path):
    path = tmp_path / "state" / "reviewer_keys.json"
    keys = signing.ensure_key_file(path)
    assert set(keys) == {"scripted", "terminal"}
    assert signing.public_hex(keys["scripted"]) != signing.public_hex(keys["terminal"])
    assert stat.S_IMODE(path.stat().st_mode) == 0o644  # public keys: nothing secret
    private = signing.private_dir(path)
    assert stat.S_IMODE(private.stat().st_mode) == 0o700
    assert sorted(p.name for p in private.iterdir()) == ["scripted.key", "terminal.key"]
    assert all(stat.S_IMODE(p.stat().st_mode) == 0o600 for p in private.iterdir())
    for r in ("scripted", "terminal"):
        assert signing.public_hex(signing.load_private_key(path, r).public_key()) == signing.public_hex(keys[r])
    text = path.read_text()
    again = signing.ensure_key_file(path)
    assert path.read_text() == text and {r: signing.public_hex(k) for r, k in again.items()} == {
        r: signing.public_hex(k) for r, k in keys.items()
    }
    # A reviewer it lacks is added; the others keep their keys.
    more = signing.ensure_key_file(path, ["alice", "scripted"])
    assert set(more) == {"scripted", "terminal", "alice"}
    assert signing.public_hex(more["scripted"]) == signing.public_hex(keys["scripted"])
    assert sorted(p.name for p in path.parent.iterdir()) == ["reviewer_keys.json", "reviewer_keys.private"]


def test_key_files_open_to_others_or_malformed_or_of_the_old_kind_are_refused(tmp_path):
    path = tmp_path / "keys.json"
    signing.ensure_key_file(path)
    os.chmod(path, 0o666)
    with pytest.raises(signing.KeyFileError, match="other users may change this key file"):
        signing.load_keys(path)
    os.chmod(path, 0o644)
    private = signing.private_dir(path) / "terminal.key"
    os.chmod(private, 0o640)
    with pytest.raises(signing.KeyFileError, match="chmod 600"):
        signing.load_private_key(path, "terminal")
    with pytest.raises(signing.KeyFileError, match="'bob' has no private key on this host"):
        signing.load_private_key(path, "bob")
    with pytest.raises(signing.KeyFileError, match="no such key file"):
        signing.load_keys(tmp_path / "missing.json")
    for bad, why in [
        ("{nope", "not JSON"),
        ('{"format": "lwm-reviewer-public-keys", "version": 2, "keys": {"alice": "abcd"}}', "32 bytes"),
        ('{"format": "lwm-reviewer-public-keys", "version": 2, "keys": {"a b": "00"}}', "an id and 64 hex digits"),
        ('{"keys": {}}', "not a key file"),
        ('{"format": "lwm-reviewer-keys", "version": 1, "keys": {}}', "shared HMAC keys"),
    ]:
        path.write_text(bad)
        with pytest.raises(signing.KeyFileError, match=why):
            signing.load_keys(path)
    # The launcher replaces a file of the old shared keys with key pairs of each reviewer's own.
    assert set(signing.ensure_key_file(path, ["alice"])) == {"alice"}


def test_a_reviewer_added_to_the_key_file_later_is_trusted_without_a_restart(tmp_path):
    """A person who joins a running system (the page's "who is reviewing?") gets a key pair; the
    planner's keyring, read at its start, reads the public file again when it first sees them."""
    path = tmp_path / "keys.json"
    signing.ensure_key_file(path)
    ring = signing.Keyring(signing.load_keys(path), str(path), path)
    restricted = ring.only(["terminal"])
    signing.ensure_key_file(path, ["bob"])
    payload = signing.sign("review_feedback", APPROVE, "bob", signing.load_private_key(path, "bob"))
    assert ring.verify("review_feedback", payload) == "bob"
    payload = signing.sign("review_feedback", APPROVE, "bob", signing.load_private_key(path, "bob"))
    with pytest.raises(signing.UntrustedReviewer, match="'bob', who is not trusted"):
        restricted.verify("review_feedback", payload)  # a fixed list of trusted reviewers stays fixed
    # A key removed from the file is dropped at the next reread.
    keys = signing.load_keys(path)
    del keys["bob"]
    signing._write(path, keys, replace=True)
    signing.ensure_key_file(path, ["carol"])
    carol = signing.sign("review_feedback", APPROVE, "carol", signing.load_private_key(path, "carol"))
    assert ring.verify("review_feedback", carol) == "carol"
    payload = signing.sign("review_feedback", APPROVE, "bob", signing.load_private_key(path, "bob"))
    with pytest.raises(signing.UntrustedReviewer):
        ring.verify("review_feedback", payload)


def test_a_keyring_without_its_file_trusts_the_file_once_it_is_made(tmp_path):
    path = tmp_path / "keys.json"
    ring = signing.Keyring({}, f"{path} (missing)", path)
    signing.ensure_key_file(path, ["alice"])
    signed = signing.sign("review_feedback", APPROVE, "alice", signing.load_private_key(path, "alice"))
    assert ring.verify("review_feedback", signed) == "alice"
