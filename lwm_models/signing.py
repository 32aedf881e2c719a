"""Who may approve: reviewer identities and Ed25519 signatures on the feedback the system learns
from (review feedback, labels, a person's manual).

Each reviewer (each person, and the scripted reviewer) has a private key of their own, and signs
with it; the nodes that take feedback (the planner, the world-model server) hold only the reviewers'
public keys. So a node that can check a reviewer's signature cannot make one, and a reviewer
cannot sign as another. A node refuses anything else: unsigned, signed by a reviewer it does not
trust, a signature that does not match (forged, altered, or made with another key), one made too
long ago, or one it has taken before (a replay).

What is signed (`signed_bytes`): the prefix `lwm-signature-v2`, a newline, the message kind
(e.g. `review_feedback`), a newline, and the payload without its `signature` field as canonical
JSON (`json.dumps(payload, sort_keys=True, separators=(",", ":"))`, ASCII, no NaN). The kind keeps
a signature from being valid for another message type; the payload includes `reviewer` (one
reviewer's signature cannot be passed off as another's), `review_id` and `plan_id` (or
`request_id`: an approval cannot be moved to another plan), `signed_at` (Unix time) and a random
`nonce`. A verifier takes a signature made at most `window` seconds from its own clock and a nonce
it has not taken within that window; the planner also remembers the nonces in its ledger across
restarts (lwm_nodes/planner_node.py).

Key files:
- the public keys (`load_keys`), e.g. logs/reviewer_keys.json, what every verifier reads:
    {"format": "lwm-reviewer-public-keys", "version": 2, "keys": {"alice": "<64 hex digits>", ...}}
  It must not be writable by others (whoever adds a key to it is trusted);
- each reviewer's private key (`load_private_key`), in the directory beside it with the suffix
  `.private` (logs/reviewer_keys.private/alice.key), mode 0600 in a 0700 directory:
    {"format": "lwm-reviewer-private-key", "version": 2, "reviewer": "alice", "seed": "<64 hex digits>"}
  Only the host where that reviewer signs needs it.
"""

from __future__ import annotations

import json
import os
import re
import secrets
import stat
import tempfile
import threading
import time
from collections.abc import Iterable, Mapping
from pathlib import Path

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from cryptography.hazmat.primitives.serialization import Encoding, NoEncryption, PrivateFormat, PublicFormat

from .errors import LwmError

FORMAT = "lwm-reviewer-public-keys"
PRIVATE_FORMAT = "lwm-reviewer-private-key"
OLD_FORMAT = "lwm-reviewer-keys"  # the shared HMAC keys of version 1, before 2026-11-27
FORMAT_VERSION = 2
KEY_BYTES = 32
DOMAIN = b"lwm-signature-v2"
WINDOW_S = 300.0  # how old (or how far ahead of this clock) a signature may be
DEFAULT_REVIEWERS = ("scripted", "terminal")  # the launcher's two reviewers: simulated and at a terminal
DEFAULT_KEY_FILE = Path("logs") / "reviewer_keys.json"  # the launcher's default log directory
REVIEWER_ID = re.compile(r"[A-Za-z0-9_.-]{1,64}")


class SigningError(LwmError, ValueError):
    """Feedback that must not be taken, or key material that cannot be used."""


class KeyFileError(SigningError):
    """A key file that is missing, malformed, or open to other users."""


class UnsignedPayload(SigningError):
    """Feedback without a signature or without a reviewer."""


class UntrustedReviewer(SigningError):
    """Feedback signed by a reviewer this node does not trust (or has no key for)."""


class BadSignature(SigningError):
    """A signature that does not match the payload and the reviewer's key."""


class StaleSignature(SigningError):
    """A signature made longer ago (or further ahead) than the verifier's window."""


class ReplayedSignature(SigningError):
    """A signed payload the verifier has taken before."""


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


def sign(kind: str, payload: Mapping, reviewer: str, key: Ed25519PrivateKey, now: float | None = None) -> dict:
    """A copy of the payload naming the reviewer, stamped with the time and a fresh nonce, and
    carrying its signature. The payload must be complete (its version included): a field added
    after signing breaks the signature."""
    body = {**payload, "reviewer": check_reviewer_id(reviewer)}
    body.pop("signature", None)
    body["signed_at"] = round(time.time() if now is None else now, 3)
    body["nonce"] = secrets.token_hex(12)
    return {**body, "signature": key.sign(signed_bytes(kind, body)).hex()}


def public_hex(key: Ed25519PublicKey) -> str:
    return key.public_bytes(Encoding.Raw, PublicFormat.Raw).hex()


class Keyring:
    """The reviewers a node trusts, with their public keys, and the nonces it has taken. A keyring
    read from a key file (`path`) reads it again when a reviewer it does not know signs and the
    file changed since: a person who joins a running system (the page's "who is reviewing?",
    `--reviewer` at a second launch) is trusted without restarting the nodes, and a key removed
    from the file is then dropped too."""

    def __init__(
        self,
        keys: Mapping[str, Ed25519PublicKey],
        source: str = "",
        path: str | Path | None = None,
        window: float = WINDOW_S,
    ) -> None:
        self.keys = dict(keys)
        self.source = source  # where the keys came from, for error messages
        self.path = Path(path) if path is not None else None
        self.window = window
        self._read_at = _changed_at(self.path) if self.path is not None and self.keys else None
        self._nonces: dict[str, float] = {}  # taken within the window: nonce -> signed_at
        self._lock = threading.Lock()  # callbacks of several topics verify at once

    def verify(self, kind: str, payload: Mapping, where: str = "", now: float | None = None) -> str:
        """The reviewer who signed the payload, if this keyring trusts them, the signature is
        theirs, it is fresh and not taken before; else a SigningError that says who, where and why."""
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
        try:
            key.verify(bytes.fromhex(sig), signed_bytes(kind, payload))
        except (InvalidSignature, ValueError, TypeError):
            raise BadSignature(
                f"{at}{kind} from reviewer {reviewer!r}: bad signature (forged, altered, or signed with another key)"
            ) from None
        self._take(kind, reviewer, payload, at, time.time() if now is None else now)
        return reviewer

    def _take(self, kind: str, reviewer: str, payload: Mapping, at: str, now: float) -> None:
        signed_at, nonce = payload.get("signed_at"), payload.get("nonce")
        if not isinstance(signed_at, int | float) or isinstance(signed_at, bool) or not isinstance(nonce, str):
            raise UnsignedPayload(f"{at}{kind} from reviewer {reviewer!r} has no signing time and nonce: sign it again")
        age = now - signed_at
        if abs(age) > self.window:
            when = f"{age:.0f} s ago" if age > 0 else f"{-age:.0f} s ahead of this host's clock"
            raise StaleSignature(
                f"{at}{kind} from reviewer {reviewer!r} was signed {when}; this node takes signatures of the last "
                f"{self.window:.0f} s (an old message sent again is refused: send it anew)"
            )
        with self._lock:
            self._forget(now)
            if nonce in self._nonces:
                raise ReplayedSignature(
                    f"{at}{kind} from reviewer {reviewer!r} was taken before (the same signature sent again)"
                )
            self._nonces[nonce] = float(signed_at)

    def remember(self, nonce: str, signed_at: float, now: float | None = None) -> None:
        """A nonce taken before this keyring existed (the planner's ledger): refused if sent again."""
        with self._lock:
            if abs((time.time() if now is None else now) - signed_at) <= self.window:
                self._nonces[nonce] = float(signed_at)

    def _forget(self, now: float) -> None:
        for nonce in [n for n, t in self._nonces.items() if abs(now - t) > self.window]:
            del self._nonces[nonce]

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
        return Keyring(chosen, self.source, window=self.window)

    def _from(self) -> str:
        return f" in {self.source}" if self.source else ""


def _changed_at(path: Path) -> tuple[int, int, int] | None:
    """What tells a rewritten key file from the one read (it is replaced atomically: a new inode)."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


def _read_json(path: Path, forbidden: int, why: str) -> dict:
    try:
        mode = path.stat().st_mode
        text = path.read_text()
    except FileNotFoundError:
        raise KeyFileError(f"{path}: no such key file") from None
    except OSError as exc:
        raise KeyFileError(f"{path}: {exc.strerror or exc}") from None
    if os.name == "posix" and mode & forbidden:
        raise KeyFileError(f"{path}: {why} (mode {mode & 0o777:o})")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise KeyFileError(f"{path}: not JSON: {exc}") from None
    if not isinstance(data, dict):
        raise KeyFileError(f"{path}: not a key file")
    return data


def _key_bytes(path: Path, reviewer: object, hexkey: object) -> bytes:
    try:
        check_reviewer_id(reviewer)
        key = bytes.fromhex(hexkey)
    except (SigningError, TypeError, ValueError):
        raise KeyFileError(f"{path}: reviewer {reviewer!r}: an id and {KEY_BYTES * 2} hex digits") from None
    if len(key) != KEY_BYTES:
        raise KeyFileError(f"{path}: reviewer {reviewer!r}: the key must be {KEY_BYTES} bytes, not {len(key)}")
    return key


def load_keys(path: str | Path) -> dict[str, Ed25519PublicKey]:
    """The reviewers' public keys in a key file. Refuses a file other users may write: whoever
    adds a key to it is trusted."""
    path = Path(path)
    data = _read_json(path, stat.S_IWGRP | stat.S_IWOTH, "other users may change this key file; chmod go-w it")
    if data.get("format") == OLD_FORMAT:
        raise KeyFileError(
            f"{path}: shared HMAC keys of the system before 2026-11-27; each reviewer now has a key pair of their "
            f"own: remove the file and start ./run_nodes.sh (or lwm ros keys) to make new keys"
        )
    if data.get("format") != FORMAT or data.get("version") != FORMAT_VERSION:
        raise KeyFileError(f"{path}: not a key file ({FORMAT!r} version {FORMAT_VERSION})")
    keys = data.get("keys")
    if not isinstance(keys, dict):
        raise KeyFileError(f"{path}: 'keys' must map reviewer ids to hex public keys")
    return {r: Ed25519PublicKey.from_public_bytes(_key_bytes(path, r, k)) for r, k in keys.items()}


def private_dir(path: str | Path) -> Path:
    """Where the reviewers' private keys of a public key file are kept: beside it, `.private`."""
    return Path(path).with_suffix(".private")


def load_private_key(path: str | Path, reviewer: str) -> Ed25519PrivateKey:
    """Reviewer's private key, from the directory beside the public key file `path`. Refuses one
    other users may read: whoever reads it can sign as that reviewer."""
    file = private_dir(path) / f"{check_reviewer_id(reviewer)}.key"
    if not file.exists():
        raise KeyFileError(f"reviewer {reviewer!r} has no private key on this host ({file})")
    data = _read_json(file, stat.S_IRWXG | stat.S_IRWXO, "other users may access this private key; chmod 600 it")
    if data.get("format") != PRIVATE_FORMAT or data.get("version") != FORMAT_VERSION:
        raise KeyFileError(f"{file}: not a private key file ({PRIVATE_FORMAT!r} version {FORMAT_VERSION})")
    if data.get("reviewer") != reviewer:
        raise KeyFileError(f"{file}: the key of {data.get('reviewer')!r}, not of {reviewer!r}")
    return Ed25519PrivateKey.from_private_bytes(_key_bytes(file, reviewer, data.get("seed")))


def _atomic_write(path: Path, data: dict, mode: int, replace: bool) -> None:
    """Write JSON atomically with `mode` (a private file is never readable by others, not even for
    a moment). Without `replace`, an existing file wins: two launchers starting at once agree on
    the keys of whichever wrote first (FileExistsError for the other)."""
    fd, tmp = tempfile.mkstemp(prefix=".keys-", dir=path.parent)  # mkstemp creates it 0600
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=2)
            f.write("\n")
        os.chmod(tmp, mode)
        if replace:
            os.replace(tmp, path)
        else:
            os.link(tmp, path)  # fails if the file appeared meanwhile
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _write(path: Path, keys: Mapping[str, Ed25519PublicKey], replace: bool) -> None:
    """The public key file (mode 0644: nothing secret in it)."""
    data = {"format": FORMAT, "version": FORMAT_VERSION, "keys": {r: public_hex(k) for r, k in sorted(keys.items())}}
    _atomic_write(path, data, 0o644, replace)


def _new_private_key(path: Path, reviewer: str) -> Ed25519PublicKey:
    """A new key pair for `reviewer`: the private key written beside `path`; its public key."""
    folder = private_dir(path)
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    key = Ed25519PrivateKey.generate()
    seed = key.private_bytes(Encoding.Raw, PrivateFormat.Raw, NoEncryption()).hex()
    data = {"format": PRIVATE_FORMAT, "version": FORMAT_VERSION, "reviewer": reviewer, "seed": seed}
    try:
        _atomic_write(folder / f"{reviewer}.key", data, 0o600, replace=False)
    except FileExistsError:  # made meanwhile by another launcher: theirs
        return load_private_key(path, reviewer).public_key()
    return key.public_key()


def ensure_key_file(path: str | Path, reviewers: Iterable[str] = DEFAULT_REVIEWERS) -> dict[str, Ed25519PublicKey]:
    """The public keys in the key file at `path`, the file created if it does not exist (a file of
    the old shared HMAC keys is replaced); a reviewer it lacks gets a new key pair, its private key
    beside the file. Returns every public key in the file."""
    path = Path(path)
    wanted = [check_reviewer_id(r) for r in reviewers]
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        keys = load_keys(path) if path.exists() else {}
    except KeyFileError:
        if _read_json(path, 0, "").get("format") != OLD_FORMAT:
            raise
        keys = {}  # the old shared keys: every reviewer gets a pair of their own
        path.unlink()
    missing = [r for r in wanted if r not in keys]
    if missing or not path.exists():
        for r in missing:
            private = private_dir(path) / f"{r}.key"
            keys[r] = load_private_key(path, r).public_key() if private.exists() else _new_private_key(path, r)
        try:
            _write(path, keys, replace=path.exists())
        except FileExistsError:  # another launcher wrote it first: add ours to theirs
            return ensure_key_file(path, wanted)
    return keys


__all__ = [
    "BadSignature",
    "Ed25519PrivateKey",
    "KeyFileError",
    "Keyring",
    "ReplayedSignature",
    "SigningError",
    "StaleSignature",
    "UnsignedPayload",
    "UntrustedReviewer",
    "ensure_key_file",
    "load_keys",
    "load_private_key",
    "private_dir",
    "public_hex",
    "sign",
    "signed_bytes",
]
