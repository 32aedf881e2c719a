"""A manual in a person's own words that leaves facts unsure, on the whole system with the
scripted reviewer (its own ROS domain): the agent asks before it acts, the answer is a manual that
states the fact, and the world-model server and the next plan hold it (docs/reading.md)."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("lwm_interfaces")
from system_helpers import start_scripted  # noqa: E402

pytestmark = pytest.mark.system


def test_the_agent_asks_before_it_acts_and_the_answer_reaches_the_plan(tmp_path):
    """A manual in a person's own words that leaves facts unsure (the fresh held-out part's, game 0):
    the first plan asks, the scripted human answers with the truth as a manual stating the fact,
    the world-model server holds it (durably) and the agent re-plans under it, each role and
    movement it acts on then the game's."""
    from lwm_models.data.splits import load_split
    from lwm_models.ledger import Ledger

    proc, _, ledger = start_scripted(
        tmp_path, "--texts", "stress:fresh", "--answer-questions", "--teach", "none", "--approve-return", "1"
    )
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, out[-3000:]
    records = Ledger(ledger).history()
    plans = [r["payload"] for r in records if r["kind"] == "plan"]
    manuals = [r["payload"] for r in records if r["kind"] == "manual"]
    assert plans and plans[0].get("questions"), out[-3000:]  # the fresh manual of game 0 leaves facts unsure
    asked = plans[0]["questions"][0]
    answered = [m for m in manuals if m.get("facts")]
    assert answered and answered[0]["descriptions"] == manuals[0]["descriptions"]  # the same words, a fact more
    fact = answered[0]["facts"][0]
    assert (fact["entity"], fact["field"]) == (asked["entity"], asked["field"])
    truth = {e.identity: e for e in load_split("newall-test")[0].entities}
    assert fact["value"] == getattr(truth[fact["entity"]], fact["field"])
    after = next(p for p in plans if p.get("facts"))
    assert after["reason"] == "manual" and after["manual_version"] > plans[0]["manual_version"]
    assert fact in after["facts"] and not any((q["entity"], q["field"]) == (asked["entity"], asked["field"])
                                              for q in after.get("questions", []))  # fmt: skip
    final = plans[-1]
    assert all(e["role"] == truth[e["identity"]].role for e in final["roles"])
    served = (tmp_path / "logs" / "world_model.log").read_text()
    assert f"manual version {after['manual_version']} from human" in served
    state = json.loads((tmp_path / "logs" / "world_model_state.json").read_text())
    assert fact in state["agents"][""]["facts"]  # a restarted server serves it too
