"""What a person can take back in a review: their corrections, teaching (with its labels),
demonstrations and manuals, newest first.

The planner's ledger holds a review's whole story, so what is still in force is worked out from it
alone, the same way by the planner (which takes back learning), by the reviewer's node (which takes
back a manual by sending the one before it again) and after any restart:

- a learning answer (feedback `corrections`, `imitate`, `demonstrations`) is a change; feedback
  `undo` takes back the newest learning change still in force;
- a manual recorded after the review's first is a change (a person's new manual, or an answer to
  a question about it); a manual whose source is `undo` takes back the newest manual change.

Taking back a change restores what was in force before it: the policy saved before a learning
answer (the planner saves one after each), or the manual before a manual change.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from .agent import FeedbackError

LEARNING = ("corrections", "imitate", "demonstrations")
UNDO_SOURCE = "undo"  # the source of a manual sent to take back the manual change before it
WHAT = {"corrections": "your corrections", "imitate": "your teaching and its labels",
        "demonstrations": "your demonstrations"}  # fmt: skip


@dataclass(frozen=True)
class Change:
    """One of the person's changes still in force. `record`: its ledger record; `before`: for a
    manual, the manual record in force before it."""

    kind: str  # "learning" or "manual"
    record: dict
    before: dict | None = None

    def words(self) -> str:
        """The change, as the person hears what was taken back."""
        p = self.record["payload"]
        if self.kind == "manual":
            return f"manual v{p['manual_version']}"
        return f"{WHAT[p['decision']]} (on plan {p['plan_id']})"


def changes(history: Sequence[dict]) -> list[Change]:
    """The person's changes still in force in a review's records (ledger order), oldest first."""
    stack: list[Change] = []
    manual: dict | None = None  # the manual record in force

    def take_back(kind: str) -> None:
        for i in range(len(stack) - 1, -1, -1):
            if stack[i].kind == kind:
                del stack[i]
                return

    for rec in history:
        p = rec["payload"]
        if rec["kind"] == "manual":
            if p.get("source") == UNDO_SOURCE:
                take_back("manual")
            elif manual is not None:
                stack.append(Change("manual", rec, manual))
            manual = rec
        elif rec["kind"] == "feedback":
            if p["decision"] in LEARNING:
                stack.append(Change("learning", rec))
            elif p["decision"] == "undo":
                take_back("learning")
    return stack


def last_change(history: Sequence[dict]) -> Change:
    """The newest change still in force; FeedbackError in plain words when there is none."""
    left = changes(history)
    if not left:
        raise FeedbackError(
            "nothing to take back: this review has no correction, teaching, demonstration or new manual of yours "
            "in force"
        )
    return left[-1]


def manual_before(change: Change) -> dict:
    """The manual message that takes back a manual change: the manual before it, sent again."""
    before = change.before["payload"]
    return {"descriptions": list(before["descriptions"]), "facts": list(before.get("facts", [])),
            "source": UNDO_SOURCE}  # fmt: skip


def policy_before(history: Sequence[dict], change: Change) -> dict | None:
    """The policy record in force before a learning change (None: the policy the review began with)."""
    saved = [rec for rec in history if rec["kind"] == "policy" and rec["id"] < change.record["id"]]
    return saved[-1]["payload"] if saved else None


__all__ = ["LEARNING", "UNDO_SOURCE", "Change", "changes", "last_change", "manual_before", "policy_before"]
