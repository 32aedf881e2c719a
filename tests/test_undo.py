"""What a person can take back, worked out from a review's ledger records alone (agent/undo.py)."""

from __future__ import annotations

import pytest

from lwm_models.agent.agent import FeedbackError
from lwm_models.agent.undo import changes, last_change, manual_before, policy_before


def story(*events: tuple[str, dict]) -> list[dict]:
    return [{"id": i, "kind": kind, "payload": payload} for i, (kind, payload) in enumerate(events, 1)]


def manual(version: int, source: str = "human", facts: list | None = None) -> tuple[str, dict]:
    return "manual", {"manual_version": version, "descriptions": [f"v{version}"] * 3, "source": source,
                      **({"facts": facts} if facts else {})}  # fmt: skip


def feedback(decision: str, plan: int) -> tuple[str, dict]:
    return "feedback", {"decision": decision, "plan_id": plan}


def test_changes_are_taken_back_newest_first_each_by_its_own_kind():
    history = story(
        manual(1, "env"),  # the manual the review opened under: no change of the person's
        ("policy", {"path": "p0", "after": 1}),
        feedback("reject", 1),  # changes nothing the agent knows
        feedback("corrections", 2),
        ("policy", {"path": "p1", "after": 4}),
        manual(2, facts=[{"identity": "dog"}]),  # an answer to a question
        feedback("imitate", 3),
        ("policy", {"path": "p2", "after": 7}),
    )
    left = changes(history)
    assert [(c.kind, c.record["id"]) for c in left] == [("learning", 4), ("manual", 6), ("learning", 7)]
    assert last_change(history).words() == "your teaching and its labels (on plan 3)"
    assert policy_before(history, left[-1]) == {"path": "p1", "after": 4}
    assert policy_before(history, left[0]) == {"path": "p0", "after": 1}

    history.append({"id": 9, "kind": "feedback", "payload": {"decision": "undo", "plan_id": 4}})
    assert last_change(history).words() == "manual v2"
    assert manual_before(last_change(history)) == {"descriptions": ["v1"] * 3, "facts": [], "source": "undo"}
    history.append({"id": 10, "kind": "manual", "payload": {**manual(3, "undo")[1], "descriptions": ["v1"] * 3}})
    assert last_change(history).words() == "your corrections (on plan 2)"
    history.append({"id": 11, "kind": "feedback", "payload": {"decision": "undo", "plan_id": 5}})
    with pytest.raises(FeedbackError, match="nothing to take back"):
        last_change(history)


def test_an_undo_takes_back_its_own_kind_even_when_the_other_kind_is_newer():
    history = story(manual(1, "env"), feedback("corrections", 1), manual(2), feedback("undo", 2))
    assert [(c.kind, c.record["id"]) for c in changes(history)] == [("manual", 3)]
