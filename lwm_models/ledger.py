"""The review ledger: every plan, feedback, manual version and execution report, in SQLite.

Each record is one committed transaction written as it happens (WAL mode), so a node killed at
any moment loses nothing it had acknowledged. `lwm ledger show` prints a review's history; the
review page reads it too, read-only (the planner is its one writer).
"""

from __future__ import annotations

import json
import sqlite3
import time
from pathlib import Path
from urllib.parse import quote

from .run_dirs import DEFAULT_LEDGER

KINDS = ("plan", "feedback", "manual", "report", "label_request", "labels", "policy", "self_teaching")


class Ledger:
    def __init__(self, path: str | Path = DEFAULT_LEDGER, read_only: bool = False) -> None:
        """read_only: for readers beside the writing planner (the review page); SQLite itself
        refuses their writes, and a missing ledger raises FileNotFoundError instead of being made."""
        self.path = Path(path)
        if read_only:
            if not self.path.is_file():
                raise FileNotFoundError(f"no ledger at {self.path}")
            uri = f"file:{quote(str(self.path.resolve()))}?mode=ro"
            self.db = sqlite3.connect(uri, uri=True, timeout=30, isolation_level=None, check_same_thread=False)
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.db = sqlite3.connect(self.path, timeout=30, isolation_level=None, check_same_thread=False)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=FULL")
        self.db.execute(
            "CREATE TABLE IF NOT EXISTS records (id INTEGER PRIMARY KEY AUTOINCREMENT, review_id TEXT NOT NULL, "
            "kind TEXT NOT NULL, time REAL NOT NULL, payload TEXT NOT NULL)"
        )
        self.db.execute("CREATE INDEX IF NOT EXISTS by_review ON records (review_id, id)")

    def record(self, review_id: str, kind: str, payload: dict) -> int:
        if kind not in KINDS:
            raise ValueError(f"unknown ledger record kind {kind!r}; known: {KINDS}")
        cur = self.db.execute(
            "INSERT INTO records (review_id, kind, time, payload) VALUES (?, ?, ?, ?)",
            (review_id, kind, time.time(), json.dumps(payload)),
        )
        return int(cur.lastrowid)

    def history(self, review_id: str | None = None) -> list[dict]:
        if review_id is None:
            rows = self.db.execute("SELECT id, review_id, kind, time, payload FROM records ORDER BY id").fetchall()
        else:
            rows = self.db.execute(
                "SELECT id, review_id, kind, time, payload FROM records WHERE review_id = ? ORDER BY id", (review_id,)
            ).fetchall()
        return [{"id": i, "review_id": r, "kind": k, "time": t, "payload": json.loads(p)} for i, r, k, t, p in rows]

    def reviews(self) -> list[str]:
        return [r for (r,) in self.db.execute("SELECT review_id FROM records GROUP BY review_id ORDER BY MIN(id)")]

    def summaries(self) -> list[dict]:
        """One entry per review, in the order they began: when it began and was last written, how
        many records of each kind, and its last report (None while it has none)."""
        out: dict[str, dict] = {}
        rows = self.db.execute(
            "SELECT review_id, kind, COUNT(*), MIN(time), MAX(time) FROM records GROUP BY review_id, kind "
            "ORDER BY MIN(id)"
        )
        for review, kind, n, first, last in rows:
            s = out.setdefault(review, {"review_id": review, "first": first, "last": last, "counts": {}})
            s["report"] = None
            s["first"], s["last"] = min(s["first"], first), max(s["last"], last)
            s["counts"][kind] = n
        reports = self.db.execute(
            "SELECT review_id, payload FROM records WHERE id IN "
            "(SELECT MAX(id) FROM records WHERE kind = 'report' GROUP BY review_id)"
        )
        for review, payload in reports:
            p = json.loads(payload)
            keep = ("plan_id", "outcome", "real_return", "imagined_return", "steps")
            out[review]["report"] = {k: p.get(k) for k in keep}
        return list(out.values())

    def close(self) -> None:
        self.db.close()


def describe(record: dict) -> str:
    """One line per record, for `lwm ledger show`."""
    when = time.strftime("%H:%M:%S", time.localtime(record["time"]))
    return f"{when} #{record['id']} {headline(record)}"


def headline(record: dict) -> str:
    """What a record says, in a line (the review page lists these)."""
    p = record["payload"]
    if record["kind"] == "plan":
        what = (
            f"plan {p['plan_id']} (manual v{p['manual_version']}): {len(p['actions'])} steps, "
            f"imagined return {p['imagined_return']:+.2f}"
        )
    elif record["kind"] == "feedback":
        detail = {"corrections": lambda: f" {p['corrections']}", "manual": lambda: f" {p['manual']}"}.get(
            p["decision"], lambda: ""
        )()
        by = f" by {p['reviewer']}" if p.get("reviewer") else ""
        what = f"feedback on plan {p['plan_id']}: {p['decision']}{detail}{by}"
    elif record["kind"] == "manual":
        what = f"manual v{p['manual_version']} from {p.get('source', '?')}: {p['descriptions']}"
    elif record["kind"] == "label_request":
        what = f"label request {p['request_id']} (round {p['round']}/{p['rounds']}): {p['states']} states"
    elif record["kind"] == "labels":
        what = f"labels for request {p['request_id']}: {p['labels']} state(s)"
    elif record["kind"] == "self_teaching":
        roles = ", ".join(f"{e['identity']} {e['role']} ({e['p']:.0%})" for e in p["roles"])
        what = f"taught itself from the manual: {p['rounds']} rounds, {p['self_labelled']} states; roles: {roles}"
    elif record["kind"] == "policy":
        what = (
            f"policy saved after record #{p.get('after')}: {p['labelled']} state(s) labelled by a reviewer "
            f"({p['path']})"
        )
    else:
        what = (
            f"executed plan {p['plan_id']}: real return {p['real_return']:+.2f} "
            f"(imagined {p['imagined_return']:+.2f}), {p['steps']} steps, {p['outcome']}"
        )
    return what
