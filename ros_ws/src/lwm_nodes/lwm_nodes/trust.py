"""Reviewer signatures in the nodes: parameters and thin adapters over lwm_models.signing.

A node that learns from feedback (planner: review/feedback and review/labels; world-model server:
feedback/manual) declares `keys_file` (the reviewers' public keys), `trusted` and
`signature_window`, and takes a payload only if a trusted reviewer signed it recently and it was
not taken before; the human-feedback node (and the fleet page) declares `keys_file` and `reviewer`
and signs what it publishes with that reviewer's private key, kept beside the key file.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path

from rclpy.node import Node

from lwm_models import messages, signing


def _keys_file(node: Node) -> Path:
    # The launcher passes its key file; a node started by hand looks where the launcher's default is.
    return Path(node.declare_parameter("keys_file", str(signing.DEFAULT_KEY_FILE)).value)


def declare_keyring(node: Node) -> signing.Keyring:
    """Parameters `keys_file` (the reviewers' public keys), `trusted` (comma-separated reviewer ids;
    empty: every reviewer in the key file) and `signature_window` (seconds a signature stays
    good). Without a key file the node trusts no one (it still serves; every feedback is refused
    and reported); a malformed key file, one others may change, or a trusted id without a key,
    stops the node at start."""
    path = _keys_file(node)
    trusted = [r.strip() for r in node.declare_parameter("trusted", "").value.split(",") if r.strip()]
    window = float(node.declare_parameter("signature_window", signing.WINDOW_S).value)
    if path.exists() or trusted:
        keyring = signing.Keyring(signing.load_keys(path), str(path), path, window)
        keyring = keyring.only(trusted) if trusted else keyring
        also = "" if trusted else "; reviewers added to the file later are trusted as they come"
        node.get_logger().info(f"trusted reviewers: {', '.join(sorted(keyring.keys)) or 'none'} (keys in {path}{also})")
        return keyring
    node.get_logger().warning(f"no key file at {path}: this node refuses all feedback until the file is made")
    return signing.Keyring({}, f"{path} (missing)", path, window)


def verified(
    keyring: signing.Keyring, kind: str, topic: str, handler: Callable[[dict], str | None]
) -> Callable[[dict], str | None]:
    """The handler, called only for payloads a trusted reviewer signed; anything else raises a
    SigningError that names the reviewer, the topic and the reason (JsonNode reports it on
    /lwm/errors and the handler never sees the payload)."""

    def check(payload: dict) -> str | None:
        keyring.verify(kind, payload, topic)
        return handler(payload)

    return check


class Signer:
    """Signs payloads as one reviewer, with that reviewer's private key (beside the key file). A
    node without it still starts (it may only display); publishing then fails with the reason.
    An empty `reviewer` parameter means nobody yet: the page asks who is reviewing (`become`)."""

    def __init__(self, node: Node, default_reviewer: str) -> None:
        self.path = _keys_file(node)
        self.reviewer = node.declare_parameter("reviewer", default_reviewer).value
        self.key: signing.Ed25519PrivateKey | None = None
        self.problem = "nobody has said who is reviewing"
        self.lock = threading.Lock()
        if self.reviewer:
            signing.check_reviewer_id(self.reviewer)
            try:
                self.key = signing.load_private_key(self.path, self.reviewer)
                self.problem = ""
            except signing.KeyFileError as exc:
                self.problem = str(exc)
        if self.key is None:
            node.get_logger().warning(f"cannot sign: {self.problem}; the planner will refuse this node's feedback")
        else:
            node.get_logger().info(f"signing as reviewer {self.reviewer!r} (key in {signing.private_dir(self.path)})")

    def become(self, reviewer: str) -> str:
        """Sign as `reviewer` from now on, with their own key (a key pair made if they have none:
        the planner and world-model server read the public key file again when they first see
        the name)."""
        reviewer = signing.check_reviewer_id(reviewer)
        signing.ensure_key_file(self.path, [reviewer])
        key = signing.load_private_key(self.path, reviewer)
        with self.lock:
            self.reviewer, self.key, self.problem = reviewer, key, ""
        return reviewer

    def sign(self, kind: str, payload: dict) -> dict:
        with self.lock:
            reviewer, key, problem = self.reviewer, self.key, self.problem
        if key is None:
            raise signing.SigningError(f"not signed: {problem}")
        # The version is part of what is signed, so it is set before signing.
        return signing.sign(kind, {"version": messages.version(kind), **payload}, reviewer, key)

    def publisher(self, publish: Callable[[dict], None], kind: str) -> Callable[[dict], None]:
        return lambda payload: publish(self.sign(kind, payload))
