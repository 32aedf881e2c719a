"""The ledger as the review page reads it: read-only beside the writing planner, one summary per
review, each record as a line (and frames for plans and reports); a label request's states in the
order a person follows them; the label checks the planner and the human node share."""

from __future__ import annotations

import sqlite3

import pytest

from lwm_models.agent.agent import FeedbackError
from lwm_models.agent.review import check_labels
from lwm_models.agent.review_view import history_view, label_request_view
from lwm_models.ledger import Ledger
from lwm_models.messages import schema

REQUEST = schema("label_request")["examples"][0]  # 3 states: trajectory 0 at steps 0 and 1, trajectory 1 at step 0
OBS = REQUEST["observations"][0]


def test_a_reader_sees_what_the_writer_commits_and_cannot_write(tmp_path):
    path = tmp_path / "ledger.sqlite"
    with pytest.raises(FileNotFoundError, match="no ledger at"):
        Ledger(path, read_only=True)
    writer = Ledger(path)
    writer.record("r1", "plan", {"plan_id": 1})
    reader = Ledger(path, read_only=True)
    writer.record("r1", "plan", {"plan_id": 2})  # written while the reader is open
    assert [r["payload"]["plan_id"] for r in reader.history("r1")] == [1, 2]
    with pytest.raises(sqlite3.OperationalError, match="readonly"):
        reader.record("r1", "plan", {"plan_id": 3})
    reader.close()
    writer.close()


def test_summaries_count_each_kind_and_keep_the_last_report(tmp_path):
    ledger = Ledger(tmp_path / "ledger.sqlite")
    report = {"plan_id": 2, "outcome": "won", "real_return": 1.0, "imagined_return": 0.5, "steps": 7}
    for review, kind, payload in [
        ("b", "plan", {}),
        ("a", "plan", {}),
        ("b", "feedback", {}),
        ("b", "report", {**report, "outcome": "died"}),
        ("b", "report", report),
        ("a", "labels", {}),
    ]:
        ledger.record(review, kind, payload)
    summaries = ledger.summaries()
    assert [s["review_id"] for s in summaries] == ["b", "a"]  # in the order they began
    b, a = summaries
    assert b["counts"] == {"plan": 1, "feedback": 1, "report": 2} and b["report"] == report
    assert a["counts"] == {"plan": 1, "labels": 1} and a["report"] is None
    assert b["first"] <= b["last"]


def test_history_view_lines_and_frames(tmp_path):
    ledger = Ledger(tmp_path / "ledger.sqlite")
    plan = {"plan_id": 1, "manual_version": 2, "actions": [3], "imagined_return": 0.5, "observations": [OBS, OBS]}
    ledger.record("r", "plan", plan)
    ledger.record("r", "feedback", {"plan_id": 1, "decision": "imitate", "reviewer": "terminal"})
    ledger.record("r", "labels", {"request_id": 1, "labels": 3})
    view = history_view(ledger.history("r"))
    assert [v["text"] for v in view] == [
        "plan 1 (manual v2): 1 steps, imagined return +0.50",
        "feedback on plan 1: imitate by terminal",
        "labels for request 1: 3 state(s)",
    ]
    assert len(view[0]["frames"]) == 2 and {c["symbol"] for c in view[0]["frames"][0]} >= {"@"}
    assert "frames" not in view[1] and "signature" not in view[1]


def test_label_request_view_orders_states_by_episode():
    view = label_request_view(REQUEST)
    assert view["order"] == [0, 2, 1]  # trajectory 0's two steps, then trajectory 1
    assert view["before"] == [-1, -1, 0]  # state 2 is trajectory 0 one step after state 0
    assert len(view["frames"]) == 3


def test_label_request_view_of_chosen_states_orders_them_by_number():
    """A request of chosen states (the board before each comes with it) is walked by state number,
    as the terminal lists them: the page walked it by episode ("state 2", then "state 0")."""
    chosen = {**REQUEST, "trajectories": [3, 1, 0], "steps": [4, 2, 7], "previous": [OBS, OBS, OBS]}
    assert label_request_view(chosen)["order"] == [0, 1, 2]


@pytest.mark.parametrize(
    ("states", "actions", "error"),
    [
        ([0, 1], [3], "2 states but 1 actions"),
        ([3], [3], "state 3 was never shown"),
        ([1, 1], [3, 3], "labelled twice"),
    ],
)
def test_check_labels_refuses_what_does_not_fit_the_request(states, actions, error):
    with pytest.raises(FeedbackError, match=error):
        check_labels(REQUEST, states, actions)
    check_labels(REQUEST, [2, 0], [3, 4])  # a partial set, in any order, is fine
