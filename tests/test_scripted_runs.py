"""Whole runs of the system with the scripted reviewer, each in its own ROS domain: runs one after
another in one checkout, nodes killed mid-review, and a review recorded and played back. Each test
starts the launcher itself (minutes of the suite's time), apart from test_ros_nodes.py's shared
system, so that two test workers can run them beside it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest

from lwm_models.ledger import Ledger

pytest.importorskip("rclpy")
pytest.importorskip("lwm_interfaces")
from lwm_nodes import domains  # noqa: E402
from system_helpers import node_pid, start_scripted, wait_for  # noqa: E402

pytestmark = pytest.mark.system


def test_every_run_in_one_checkout_starts_clean_and_resume_shows_a_finished_review(tmp_path):
    """Two `./run_nodes.sh --scripted` in a row in one directory: each reviews its episode to the
    end in a run directory of its own (logs/runs/<time>). --resume continues the newest: its
    finished review is shown again, not redone; naming an earlier run's directory without
    --resume is refused, not silently continued."""
    env = {
        **os.environ,
        "ROS_DOMAIN_ID": str(domains.claim()),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
    }
    env.pop("LWM_LOGS", None)
    env.pop("LWM_LEDGER", None)
    cmd = [sys.executable, "-m", "lwm_nodes.launcher", "--scripted", "--quiet", "--iterations", "2", "--futures", "2"]

    def launch(*extra: str) -> subprocess.CompletedProcess:
        return subprocess.run([*cmd, *extra], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)

    runs = []
    for _ in range(2):
        done = launch()
        assert done.returncode == 0 and "SUMMARY review newall-test:0:0" in done.stdout, done.stdout[-3000:]
        assert "a new run in logs/runs/" in done.stdout
        runs.append((tmp_path / "logs" / "latest").resolve())
        kinds = [r["kind"] for r in Ledger(runs[-1] / "ledger.sqlite").history()]
        # reviewed from its start: the policy it opened with (what undo returns to), then the agent
        # teaches itself before its first plan
        assert kinds.count("report") == 1 and kinds[:5] == ["manual", "policy", "self_teaching", "policy", "plan"]
    assert runs[0] != runs[1] and runs[0].parent == runs[1].parent == tmp_path / "logs" / "runs"
    resumed = launch("--resume")
    assert resumed.returncode == 0 and "resuming the run in" in resumed.stdout, resumed.stdout[-3000:]
    assert (
        "1 review(s) in its ledger, 1 finished" in resumed.stdout and "SUMMARY review newall-test:0:0" in resumed.stdout
    )
    assert "finished earlier" in (runs[1] / "planner.log").read_text()
    assert [r["kind"] for r in Ledger(runs[1] / "ledger.sqlite").history()].count("report") == 1  # not redone
    refused = launch("--log-dir", str(runs[0]))
    assert refused.returncode == 2 and "--resume" in refused.stderr and "Traceback" not in refused.stderr


def test_killed_nodes_mid_review_are_restarted_and_the_review_resumes(tmp_path):
    """Two failures in one scripted review (one run of the system, to keep the suite short): the
    planner killed after its first plan resumes from the ledger; the world-model server killed
    while online imitation labels resumes with the manual it had."""
    proc, env, ledger_path = start_scripted(tmp_path)
    from lwm_models.ledger import Ledger

    def kinds() -> list[str]:
        return [r["kind"] for r in Ledger(ledger_path).history()] if ledger_path.is_file() else []

    assert wait_for(lambda: "plan" in kinds(), timeout=180), "no plan recorded"
    os.kill(node_pid("lwm_nodes.planner_node", env["ROS_DOMAIN_ID"]), signal.SIGKILL)
    labelled_before = kinds().count("labels")
    assert wait_for(lambda: kinds().count("labels") > labelled_before, timeout=240), "no online-imitation round"
    os.kill(node_pid("lwm_nodes.world_model_node", env["ROS_DOMAIN_ID"]), signal.SIGKILL)
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, out[-3000:]
    assert "planner exited with -9; restart 1" in out
    assert "world_model exited with -9; restart 1" in out
    assert "resumed from the ledger" in (tmp_path / "logs" / "planner.log").read_text()
    records = Ledger(ledger_path).history()
    kinds_ = [r["kind"] for r in records]
    assert kinds_.count("report") == 1 and kinds_.count("label_request") == kinds_.count("labels") >= 1
    plan_ids = [r["payload"]["plan_id"] for r in records if r["kind"] == "plan"]
    assert plan_ids == sorted(set(plan_ids)), f"a plan was recorded twice: {plan_ids}"
    assert sum(r["kind"] == "manual" and r["payload"]["source"] == "env" for r in records) == 1
    # The restarted world-model server kept the manual's version: every plan says version 1.
    assert {r["payload"]["manual_version"] for r in records if r["kind"] == "plan"} == {1}


def test_scripted_review_loop_end_to_end_recorded_and_played_back(tmp_path):
    """The scripted human speaks first (--language: the true manual in other words on
    /feedback/manual), then reviews the plan imagined under it, teaches, and approves. With
    --record every message of it is in an MCAP file, as many per topic as the planner's ledger
    took (feedback it refused is on /lwm/errors instead); then `lwm ros play` republishes it and a
    subscriber receives the recorded plans. (One run of the system for both, to keep the suite short.)"""
    from lwm_models import recording
    from lwm_models.ledger import Ledger

    path = tmp_path / "review.mcap"
    proc, env, ledger = start_scripted(tmp_path, "--language", "--record", str(path))
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, out[-3000:]
    assert "recorder exit code 0" in out
    assert "human finished" in out
    summary = [line for line in (tmp_path / "logs" / "human.log").read_text().splitlines() if "SUMMARY" in line]
    assert summary and "real return" in summary[0]
    shown = subprocess.run(
        [sys.executable, "-m", "lwm_models.cli.main", "ledger", "show", "--path", str(ledger)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    shown_kinds = [line.split()[2] for line in shown.stdout.splitlines()[1:]]
    # The policy the review opened with (what an undo returns to); then under each manual the agent
    # taught itself before its plan (the "taught" lines).
    expected = ["manual", "policy", "taught", "policy", "plan", "manual", "taught", "policy", "plan"]
    assert shown_kinds[:9] == expected, shown_kinds
    assert "feedback" in shown_kinds and shown_kinds[-1] == "executed"
    records = Ledger(ledger).history()
    manuals = [r["payload"] for r in records if r["kind"] == "manual"]
    assert [m["source"] for m in manuals[:2]] == ["env", "human"]
    assert manuals[1]["descriptions"] != manuals[0]["descriptions"]
    plans = [r["payload"] for r in records if r["kind"] == "plan"]
    assert plans[1]["reason"] == "manual" and plans[1]["manual"] == manuals[1]["descriptions"]
    assert plans[1]["manual_version"] == plans[0]["manual_version"] + 1
    answered = {r["payload"]["plan_id"] for r in records if r["kind"] == "feedback"}
    assert plans[0]["plan_id"] not in answered and plans[1]["plan_id"] in answered

    got = list(recording.read(path))
    by_topic: dict[str, list[str]] = {}
    for m in got:
        by_topic.setdefault(m.topic, []).append(m.text)
    kinds = [r["kind"] for r in Ledger(ledger).history()]
    refused = [e for e in map(json.loads, by_topic.get("/lwm/errors", [])) if e["where"] == "/review/feedback"]
    assert len(by_topic["/planner/plan"]) == kinds.count("plan") >= 1
    assert len(by_topic["/review/feedback"]) == kinds.count("feedback") + len(refused)
    assert len(by_topic["/planner/label_request"]) == kinds.count("label_request") >= 1
    assert len(by_topic["/review/labels"]) == kinds.count("labels") >= 1
    assert len(by_topic["/planner/report"]) == kinds.count("report") == 1
    assert {"/env/state", "/env/manual", "/lwm/status"} <= set(by_topic)
    # The services' requests and responses are in it too, as service events: decoded here by the
    # mcap-ros2-support decoder from the schema in the file (its vendored parser wants type names
    # without '_', so the test's copy of the schema says JsonRequest for Json_Request).
    from mcap.reader import make_reader
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory

    events: dict[str, list] = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if schema.name == recording.EVENT_TYPE:
                named = (
                    schema.data.decode().replace("Json_Request", "JsonRequest").replace("Json_Response", "JsonResponse")
                )
                renamed = Schema(
                    id=schema.id, name="lwm_interfaces/srv/JsonEvent", encoding=schema.encoding, data=named.encode()
                )
                events.setdefault(channel.topic, []).append(DecoderFactory().decoder_for("cdr", renamed)(message.data))
    calls = events["/lwm/imagine/_service_event"]  # the planner imagines through it in every review
    requests = [json.loads(e.request[0].request) for e in calls if e.info.event_type == 1]  # REQUEST_RECEIVED
    responses = [json.loads(e.response[0].response) for e in calls if e.info.event_type == 2]  # RESPONSE_SENT
    assert requests and len(requests) == len(responses)
    assert {r.get("op", "imagine") for r in requests} >= {"open", "step"} and all(r["ok"] for r in responses)
    by_call = {e.info.sequence_number for e in calls if e.info.event_type == 1}
    assert by_call == {e.info.sequence_number for e in calls if e.info.event_type == 2}  # each answered
    assert [m.latched for m in got if m.topic == "/planner/plan"][0] and not any(
        m.latched for m in got if m.topic == "/lwm/errors"
    )

    # Play it back in a fresh domain: a subscriber receives the recorded plans, in order.
    play_env = {**env, "ROS_DOMAIN_ID": str(domains.claim())}
    ros = [sys.executable, "-m", "lwm_models.cli.main", "ros"]
    plans = by_topic["/planner/plan"]
    echo = subprocess.Popen(
        [*ros, "echo", "/planner/plan", "--latched", "--count", str(len(plans)), "--timeout", "90"],
        stdout=subprocess.PIPE,
        text=True,
        env=play_env,
    )
    played = subprocess.run(
        [*ros, "play", str(path), "--rate", "50", "--topics", "/planner/plan", "/planner/report", "--wait", "4"],
        capture_output=True,
        text=True,
        env=play_env,
        timeout=120,
        start_new_session=True,
    )
    assert played.returncode == 0, played.stderr
    assert f"played {len(plans) + 1} messages on 2 topics" in played.stdout
    echoed, _ = echo.communicate(timeout=120)
    assert [json.loads(line) for line in echoed.splitlines()] == [json.loads(text) for text in plans]
    missing = subprocess.run([*ros, "play", str(tmp_path / "none.mcap")], capture_output=True, text=True, env=play_env)
    assert missing.returncode == 2 and "cannot read the recording" in missing.stderr
