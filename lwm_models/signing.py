"""Who may approve: reviewer identities and HMAC-SHA256 signatures on the feedback the system
learns from (review feedback, labels, a person's manual).

A reviewer signs a payload with its own 32-byte key; a node that takes feedback holds the keys of
the reviewers it trusts and refuses anything else: unsigned, signed by a reviewer it does not
trust, or with a signature that does not match (forged, altered, or made with another key).

What is signed (`signed_bytes`): the prefix `lwm-signature-v1`, a newline, the message kind
(e.g. `review_feedback`), a newline, and the payload without its `signature` field as canonical
JSON (`json.dumps(payload, sort_keys=True, separators=(",", ":"))`, ASCII, no NaN). The kind keeps
a signature from being valid for another message type; the payload includes `reviewer`, so one
reviewer's signature cannot be passed off as another's, and `review_id` and `plan_id` (or
`request_id`), so an approval cannot be moved to another plan.

The key file (`load_keys`, `ensure_key_file`) is JSON, mode 0600:
    {"format": "lwm-reviewer-keys", "version": 1, "keys": {"scripted": "<64 hex digits>", ...}}
Anyone who can read it can sign as any reviewer in it.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import re
import secrets
import stat
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path

from .errors import LwmError

FORMAT = "lwm-reviewer-keys"
FORMAT_VERSION = 1
KEY_BYTES = 32
DOMAIN = b"lwm-signature-v1"
DEFAULT_REVIEWERS = ("scripted", "terminal")  # the launcher's two reviewers: simulated and at a terminal
DEFAULT_KEY_FILE = Path("logs") / "reviewer_keys.json"  # the launcher's default log directory
REVIEWER_ID = re.compile(r"[A-Za-z0-9_.-]{1,64}")


class SigningError(LwmError, ValueError):
    """Feedback that must not be taken, or key material that cannot be used."""


class KeyFileError(SigningError):
    """A key file that is missing, malformed, or readable by other users."""


class UnsignedPayload(SigningError):
    """Feedback without a signature or without a reviewer."""


class UntrustedReviewer(SigningError):
    """Feedback signed by a reviewer this node does not trust (or has no key for)."""


class BadSignature(SigningError):
    """A signature that does not match the payload and the reviewer's key."""


def check_reviewer_id(reviewer: str) -> str:
    if not isinstance(reviewer, str) or not REVIEWER_ID.fullmatch(reviewer):
        raise SigningError(f"reviewer id {reviewer!r}: use 1-64 letters, digits, '_', '.' or '-'")
    return reviewer


def signed_bytes(kind: str, payload: Mapping) -> bytes:
    """What the signature covers: the kind and the canonical JSON of the payload without its
    signature. Independent of key order and whitespace, so sender and receiver agree on it
    whatever their JSON encoder did."""
    body = {k: v for k, v in payload.items() if k != "signature"}
    try:
        text = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise SigningError(f"{kind}: the payload has no canonical JSON form: {exc}") from None
    return DOMAIN + b"\n" + kind.encode() + b"\n" + text.encode()


def signature(kind: str, payload: Mapping, key: bytes) -> str:
    return hmac.new(key, signed_bytes(kind, payload), hashlib.sha256).hexdigest()


def sign(kind: str, payload: Mapping, reviewer: str, key: bytes) -> dict:
    """A copy of the payload naming the reviewer and carrying its signature. The payload must be
    complete (its version included): a field added after signing breaks the signature."""
    body = {**payload, "reviewer": check_reviewer_id(reviewer)}
    body.pop("signature", None)
    return {**body, "signature": signature(kind, body, key)}


class Keyring:
    """The reviewers a node trusts, with their keys. A keyring read from a key file (`path`) reads
    it again when a reviewer it does not know signs and the file changed since: a person who
    joins a running system (the page's "who is reviewing?", `--reviewer` at a second launch) is
    trusted without restarting the nodes, and a key removed from the file is then dropped too."""

    def __init__(self, keys: Mapping[str, bytes], source: str = "", path: str | Path | None = None) -> None:
        self.keys = dict(keys)
        self.source = source  # where the keys came from, for error messages
        self.path = Path(path) if path is not None else None
        self._read_at = _changed_at(self.path) if self.path is not None and self.keys else None

    def verify(self, kind: str, payload: Mapping, where: str = "") -> str:
        """The reviewer who signed the payload, if this keyring trusts them and the signature is
        theirs; else a SigningError that says who, where and why."""
        at = f"{where}: " if where else ""
        reviewer = payload.get("reviewer")
        sig = payload.get("signature")
        who = f"reviewer {reviewer!r}" if reviewer else "no reviewer named"
        if not sig:
            raise UnsignedPayload(f"{at}unsigned {kind} ({who}): only signed feedback is taken")
        if not reviewer:
            raise UnsignedPayload(f"{at}signed {kind} names no reviewer")
        key = self.keys.get(reviewer)
        if key is None and self._reread():
            key = self.keys.get(reviewer)
        if key is None:
            trusted = ", ".join(sorted(self.keys)) or f"no one: no keys loaded{self._from()}"
            raise UntrustedReviewer(f"{at}{kind} from reviewer {reviewer!r}, who is not trusted (trusted: {trusted})")
        if not isinstance(sig, str) or not hmac.compare_digest(sig, signature(kind, payload, key)):
            raise BadSignature(
                f"{at}{kind} from reviewer {reviewer!r}: bad signature (forged, altered, or signed with another key)"
            )
        return reviewer

    def _reread(self) -> bool:
        """Read the key file again if it changed since it was read; True when it was. A file that
        cannot be read now (being replaced, damaged) leaves the keys as they were."""
        if self.path is None:
            return False
        changed = _changed_at(self.path)
        if changed is None or changed == self._read_at:
            return False
        try:
            self.keys = load_keys(self.path)
        except KeyFileError:
            return False
        self._read_at = changed
        return True

    def only(self, reviewers: Iterable[str]) -> Keyring:
        """The keyring restricted to these reviewers, each of whom must have a key (a fixed list:
        it does not grow when the file does)."""
        chosen = {}
        for r in reviewers:
            if r not in self.keys:
                raise KeyFileError(f"trusted reviewer {r!r} has no key{self._from()}")
            chosen[r] = self.keys[r]
        return Keyring(chosen, self.source)

    def _from(self) -> str:
        return f" in {self.source}" if self.source else ""


def _changed_at(path: Path) -> tuple[int, int, int] | None:
    """What tells a rewritten key file from the one read (it is replaced atomically: a new inode)."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


def load_keys(path: str | Path) -> dict[str, bytes]:
    """The reviewers' keys in a key file. Refuses a file other users may read or write: anyone who
    can read it can sign as every reviewer in it."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
        text = path.read_text()
    except FileNotFoundError:
        raise KeyFileError(f"{path}: no such key file") from None
    except OSError as exc:
        raise KeyFileError(f"{path}: {exc.strerror or exc}") from None
    if os.name == "posix" and mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise KeyFileError(f"{path}: other users may access this key file (mode {mode & 0o777:o}); chmod 600 it")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise KeyFileError(f"{path}: not JSON: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT or data.get("version") != FORMAT_VERSION:
        raise KeyFileError(f"{path}: not a key file ({FORMAT!r} version {FORMAT_VERSION})")
    keys = data.get("keys")
    if not isinstance(keys, dict):
        raise KeyFileError(f"{path}: 'keys' must map reviewer ids to hex keys")
    out = {}
    for reviewer, hexkey in keys.items():
        try:
            check_reviewer_id(reviewer)
            key = bytes.fromhex(hexkey)
        except (SigningError, TypeError, ValueError):
            raise KeyFileError(f"{path}: reviewer {reviewer!r}: an id and {KEY_BYTES * 2} hex digits") from None
        if len(key) != KEY_BYTES:
            raise KeyFileError(f"{path}: reviewer {reviewer!r}: the key must be {KEY_BYTES} bytes, not {len(key)}")
        out[reviewer] = key
    return out


def _write(path: Path, keys: Mapping[str, bytes], replace: bool) -> None:
    """Write the key file atomically with mode 0600 (never readable by others, not even for a
    moment). Without `replace`, an existing file wins: two launchers starting at once agree on
    the keys of whichever wrote first."""
    data = {"format": FORMAT, "version": FORMAT_VERSION, "keys": {r: k.hex() for r, k in sorted(keys.items())}}
    fd, tmp = tempfile.mkstemp(prefix=".keys-", dir=path.parent)  # mkstemp creates it 0600
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=2)
            f.write("\n")
        if replace:
            os.replace(tmp, path)
        else:
            os.link(tmp, path)  # fails if the file appeared meanwhile
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def ensure_key_file(path: str | Path, reviewers: Iterable[str] = DEFAULT_REVIEWERS) -> dict[str, bytes]:
    """The keys in the key file at `path`, created (random keys, mode 0600) if it does not exist;
    a reviewer it lacks gets a new key added. Returns every key in the file."""
    path = Path(path)
    wanted = [check_reviewer_id(r) for r in reviewers]
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.exists():
        try:
            _write(path, {r: secrets.token_bytes(KEY_BYTES) for r in wanted}, replace=False)
        except FileExistsError:
            pass
    keys = load_keys(path)
    missing = [r for r in wanted if r not in keys]
    if missing:
        keys.update({r: secrets.token_bytes(KEY_BYTES) for r in missing})
        _write(path, keys, replace=True)
    return keys
