"""The ROS 2 nodes across real processes: the launcher starts the environment and world-model server nodes
(on the shipped EMMA-LWM), and the `lwm ros` command line (its own process) talks to them over
Fast DDS on localhost."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from game_fixtures import MANUAL, OBS

from lwm_models.ledger import Ledger
from lwm_models.world.shipped import SHIPPED, SYSTEM_WORLD_MODEL, WORLD_MODELS

pytest.importorskip("rclpy")
pytest.importorskip("lwm_interfaces")
from lwm_nodes import domains  # noqa: E402
from system_helpers import node_pid, wait_for  # noqa: E402

pytestmark = pytest.mark.system


@pytest.fixture(scope="module")
def system(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ros")
    # Every node process records the checkpoint files it opens (an audit hook, loaded by Python's
    # sitecustomize from PYTHONPATH): the test can tell which process read world-model weights.
    audit = tmp / "audit"
    audit.mkdir()
    (audit / "sitecustomize.py").write_text(
        "import os, sys\n"
        "def _hook(event, args):\n"
        "    if event == 'open' and isinstance(args[0], str) and 'checkpoints' in args[0]:\n"
        f"        with open(os.path.join({str(audit)!r}, f'{{os.getpid()}}.txt'), 'a') as f:\n"
        "            f.write(args[0] + '\\n')\n"
        "sys.addaudithook(_hook)\n"
    )
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(audit), os.environ.get("PYTHONPATH", "")])),
        "ROS_DOMAIN_ID": str(domains.claim()),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "ROS_LOG_DIR": str(tmp / "roslog"),
    }
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "lwm_nodes.launcher",
            "--log-dir",
            str(tmp / "logs"),
            "--no-human",
            "--ledger",
            str(tmp / "ledger.sqlite"),
            "--quiet",
            "--max-restarts",
            "2",
            "--iterations",
            "3",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    deadline = time.monotonic() + 120
    for line in proc.stdout:
        if "nodes ready" in line:
            break
        if time.monotonic() > deadline:
            break
    assert proc.poll() is None, "launcher died"
    yield {"env": env, "tmp": tmp, "proc": proc}
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out


def lwm_ros(system, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "lwm_models.cli.main", "ros", *args],
        capture_output=True,
        text=True,
        env=system["env"],
        timeout=timeout,
    )


def signed(system, reviewer: str = "terminal") -> list[str]:
    """`lwm ros pub` options that sign as a reviewer of the launcher's key file."""
    return ["--sign", reviewer, "--keys-file", str(system["tmp"] / "logs" / "reviewer_keys.json")]


def call(system, service: str, payload: dict | str) -> dict:
    text = payload if isinstance(payload, str) else json.dumps(payload)
    proc = lwm_ros(system, "call", service, text, "--raw")
    assert proc.stdout.strip(), f"no answer from {service}: {proc.stderr}"
    answer = json.loads(proc.stdout.strip().splitlines()[-1])
    # A refusal ("ok": false) exits 1 with the reason on stderr; anything else exits 0.
    assert proc.returncode == (1 if answer.get("ok") is False else 0), proc.stderr
    assert answer.get("ok") is not False or "refused the request" in proc.stderr
    return answer


def status(system) -> dict:
    proc = lwm_ros(system, "echo", "/lwm/status", "--latched", "--count", "1", "--timeout", "10")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_graph_lists_the_nodes_and_services(system):
    # Graph discovery of a fresh process took over the default 1 s once in CI on a loaded machine.
    nodes = lwm_ros(system, "nodes", "--settle", "3").stdout.split()
    assert "/messenger_env" in nodes and "/lwm_world_model" in nodes
    services = lwm_ros(system, "services", "--settle", "3").stdout
    assert "/lwm/imagine [lwm_interfaces/srv/Json]" in services and "/env/step" in services


def test_imagine_uses_the_environment_manual_then_the_feedback(system):
    before = status(system)
    first = call(
        system, "/lwm/imagine", {"version": 1, "observation": OBS, "actions": [[1, 1, 3]], "max_steps": 3, "seed": 5}
    )
    assert first["ok"] and len(first["trajectories"]) == 1
    assert len(first["trajectories"][0]["observations"]) >= 2
    env_manual = first["manual"]
    assert env_manual != MANUAL
    pub = lwm_ros(
        system,
        "pub",
        "/feedback/manual",
        json.dumps({"version": 2, "descriptions": MANUAL, "source": "human"}),
        "--latched",
        "--kind",
        "manual",
        *signed(system),
    )
    assert pub.returncode == 0, pub.stderr
    st = wait_for(lambda: (s := status(system))["manual_source"] == "human" and s)
    assert st["manual"] == MANUAL and st["manual_version"] >= 2
    second = call(
        system, "/lwm/imagine", {"version": 1, "observation": OBS, "actions": [[1, 1, 3]], "max_steps": 3, "seed": 5}
    )
    assert second["manual"] == MANUAL and second["manual_version"] == st["manual_version"]
    # The same game in other words: the same reading, so the same imagined future (the world model
    # imagines what the words are read to say, not the wording).
    believed = [[(e["identity"], e["role"], e["movement"]) for e in s["belief"]] for s in (before, st)]
    assert believed[0] == believed[1]
    assert second["trajectories"][0]["confidence"] == first["trajectories"][0]["confidence"]


def test_environment_reset_and_step(system):
    reset = call(system, "/env/reset", {"seed": 3})
    assert reset["ok"] and reset["state"]["t"] == 0
    step = call(system, "/env/step", {"action": 3})
    assert step["ok"] and step["state"]["t"] == 1
    bad = call(system, "/env/step", {"action": 9})
    assert not bad["ok"] and "env_step_request: action" in bad["error"]


def watch_errors(system, timeout: float, publishers: int = 3) -> tuple[subprocess.Popen, list[str]]:
    """`lwm ros echo /lwm/errors` in the background, once it has matched the nodes that report
    errors (env, world-model server, planner: an event, not a sleep): the process, and the lines it prints."""
    errors = subprocess.Popen(
        [sys.executable, "-m", "lwm_models.cli.main", "ros", "echo", "/lwm/errors", "--timeout", str(timeout)]
        + ["--wait-publishers", str(publishers)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=system["env"],
    )
    ready = errors.stderr.readline()
    assert ready.startswith(f"# listening to {publishers} publisher(s)"), ready
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(errors.stdout), daemon=True).start()
    return errors, lines


def latched(system, topic: str) -> dict:
    proc = lwm_ros(system, "echo", topic, "--latched", "--count", "1", "--timeout", "20")
    assert proc.returncode == 0, f"nothing latched on {topic}"
    return json.loads(proc.stdout.strip().splitlines()[-1])


@contextlib.contextmanager
def terminal(system, name: str):
    """A person at the terminal review: a human node reading what the test types. Yields
    (type_line, said, log path); said(words) waits until the terminal printed them. The node must
    end cleanly on SIGINT."""
    log_path = system["tmp"] / f"{name}.log"
    keys = str(system["tmp"] / "logs" / "reviewer_keys.json")
    with open(log_path, "w") as log:
        human = subprocess.Popen(
            [sys.executable, "-m", "lwm_nodes.human_node", "--ros-args", "-p", f"keys_file:={keys}"],
            stdin=subprocess.PIPE, stdout=log, stderr=subprocess.STDOUT, env={**system["env"], "PYTHONUNBUFFERED": "1"},
            text=True,
        )  # fmt: skip

        def type_line(line: str) -> None:
            human.stdin.write(line + "\n")
            human.stdin.flush()

        def said(words: str, timeout: float = 60) -> bool:
            return bool(wait_for(lambda: words in log_path.read_text(), timeout=timeout))

        try:
            assert said("READY"), log_path.read_text()[-2000:]
            yield type_line, said, log_path
        finally:
            human.send_signal(signal.SIGINT)
            human.wait(timeout=30)
    assert human.returncode == 0


def start_human_node(system) -> subprocess.Popen:
    """An interactive human-feedback node (nobody types): it subscribes to the plan and report topics."""
    log = open(system["tmp"] / "human_node.log", "w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "lwm_nodes.human_node"],
        stdin=subprocess.PIPE,
        stdout=log,
        stderr=subprocess.STDOUT,
        env=system["env"],
    )
    assert wait_for(lambda: "READY" in (system["tmp"] / "human_node.log").read_text(), timeout=60)
    return proc


def test_malformed_payloads_get_errors_and_the_nodes_keep_serving(system):
    """Every topic and service a node of the system reads: junk in, a structured error on
    /lwm/errors from each reading node, and the node still serves afterwards."""
    human = start_human_node(system)
    expected = {
        ("lwm_world_model", "/feedback/manual"),
        ("lwm_world_model", "/env/manual"),
        ("planner", "/lwm/status"),
        ("planner", "/env/state"),
        ("planner", "/review/labels"),
        ("human_feedback", "/planner/label_request"),
        ("human_feedback", "/env/state"),
        ("human_feedback", "/planner/plan"),
        ("human_feedback", "/planner/report"),
        ("planner", "/review/feedback"),
        ("lwm_world_model", "/lwm/imagine"),
        ("messenger_env", "/env/reset"),
        ("messenger_env", "/env/step"),
    }
    errors, lines = watch_errors(system, 90, publishers=4)  # and the human node's
    try:
        plan = latched(system, "/planner/plan")
        base = {"version": 2, "review_id": plan["review_id"]}
        for topic, payload in [
            ("/feedback/manual", '{"version": 2, "descriptions": ["just one"]}'),
            ("/env/manual", "{not json"),
            # Schema-valid, but no game state: the same entity in two channels.
            (
                "/env/state",
                json.dumps(
                    {
                        **latched(system, "/env/state"),
                        "observation": [[2, 2, 7], [2, 7, 2], [11, 7, 7], [15, 2, 2]],
                        "t": 0,
                    }
                ),
            ),
            ("/planner/plan", "[]"),
            ("/planner/report", '{"version": 1}'),
            ("/lwm/status", '{"version": 1, "node": 3}'),
            ("/planner/label_request", '{"version": 1, "review_id": "x"}'),
            # Schema-valid, but there is no such label request.
            ("/review/labels", json.dumps({**base, "request_id": 999, "states": [0], "actions": [1]})),
            # Valid JSON for the schema, but step 99 is not in the plan: the agent rejects it.
            (
                "/review/feedback",
                json.dumps(
                    {
                        "version": 2,
                        "review_id": plan["review_id"],
                        "plan_id": plan["plan_id"],
                        "decision": "corrections",
                        "corrections": [{"step": 99, "action": 1}],
                    }
                ),
            ),
        ]:
            readers = {"/env/state": 2}.get(topic, 1)
            # Feedback is signed, so that the planner refuses it for what it says, not for who sent it.
            kind = {"/review/labels": "labels", "/review/feedback": "review_feedback"}.get(topic)
            sign = ["--kind", kind, *signed(system)] if kind else []
            sent = lwm_ros(system, "pub", topic, payload, "--raw", "-w", str(readers), "--wait", "10", *sign)
            if topic in ("/feedback/manual", "/review/labels", "/review/feedback"):  # the sender hears the refusal
                assert sent.returncode == 1 and "refused by" in sent.stderr, (topic, sent.stdout, sent.stderr)
            else:
                assert sent.returncode == 0, sent.stderr
        bad = call(system, "/lwm/imagine", "{not json")
        assert not bad["ok"] and "not JSON" in bad["error"]
        bad = call(system, "/env/reset", "[1, 2]")
        assert not bad["ok"]
        bad = call(system, "/env/step", '{"action": "up"}')
        assert not bad["ok"]

        def reports() -> list[dict]:
            return [json.loads(line) for line in list(lines) if line.strip()]

        wait_for(lambda: {(r["node"], r["where"]) for r in reports()} >= expected, timeout=60)
        got = {(r["node"], r["where"]) for r in reports()}
        assert got >= expected, f"missing error reports: {sorted(expected - got)}"
        assert all(r["error"] for r in reports())
        assert all("repeat an id" in r["error"] for r in reports() if r["where"] == "/env/state")

        # Everyone still serves: the services answer, the planner takes a corrected feedback
        # for the same plan and publishes the next plan, the human node prints it.
        ok = call(system, "/lwm/imagine", {"version": 1, "observation": OBS, "n": 2, "max_steps": 2})
        assert ok["ok"] and len(ok["trajectories"]) == 2
        assert call(system, "/env/reset", {"seed": 3})["ok"]
        assert call(system, "/env/step", {"action": 4})["ok"]
        plan = wait_for(lambda: (p := latched(system, "/planner/plan"))["review_id"].endswith(":3") and p, timeout=60)
        assert plan, "no plan for the reset episode"
        fix = {
            "version": 2,
            "review_id": plan["review_id"],
            "plan_id": plan["plan_id"],
            "decision": "corrections",
            "corrections": [{"step": 1, "action": (plan["actions"][0] + 1) % 5}],
        }
        sent = lwm_ros(system, "pub", "/review/feedback", json.dumps(fix), "--kind", "review_feedback", *signed(system))
        assert sent.returncode == 0, sent.stderr
        revised = wait_for(
            lambda: (p := latched(system, "/planner/plan"))["plan_id"] > plan["plan_id"] and p, timeout=60
        )
        assert revised and revised["review_id"] == plan["review_id"]
        # The corrected step, from the same (real, first) state, takes the corrected action.
        assert revised["actions"][0] == fix["corrections"][0]["action"]
        log = system["tmp"] / "human_node.log"
        assert wait_for(lambda: f"=== plan {revised['plan_id']} " in log.read_text(), timeout=30)
        assert human.poll() is None
    finally:
        errors.terminate()
        assert errors.wait(timeout=30) == 130
        human.send_signal(signal.SIGINT)
        human.wait(timeout=30)
    assert human.returncode == 0


MANUAL2 = [
    "the dog is the goal and it does not move.",
    "the deadly enemy is the plane, chasing you.",
    "a ball carries the secret message; it flees.",
]


def test_manual_feedback_reaches_the_plan_under_review(system):
    before = latched(system, "/planner/plan")
    manual = json.dumps({"version": 2, "descriptions": MANUAL2})
    pub = lwm_ros(system, "pub", "/feedback/manual", manual, "--kind", "manual", *signed(system))
    assert pub.returncode == 0, pub.stderr
    st = wait_for(lambda: (s := status(system))["manual"] == MANUAL2 and s)
    assert st, "the world-model server did not take the manual"
    plan = wait_for(lambda: (p := latched(system, "/planner/plan"))["manual"] == MANUAL2 and p, timeout=60)
    assert plan, "no plan under the new manual"
    assert plan["manual_version"] == st["manual_version"] > before["manual_version"]
    assert plan["review_id"] == before["review_id"] and plan["plan_id"] > before["plan_id"]
    assert plan["reason"] == "manual" and plan["futures"]["k"] >= 1


def test_bad_labels_get_errors_and_change_nothing_then_a_fixed_resend_is_taken(system):
    plan = latched(system, "/planner/plan")
    imitate = {**{k: plan[k] for k in ("review_id", "plan_id")}, "version": 2, "decision": "imitate", "rounds": 1}
    sent = lwm_ros(system, "pub", "/review/feedback", json.dumps(imitate), "--kind", "review_feedback", *signed(system))
    assert sent.returncode == 0, sent.stderr
    request = wait_for(
        lambda: (r := latched(system, "/planner/label_request"))["review_id"] == plan["review_id"] and r, timeout=60
    )
    assert request, "no label request"
    n = len(request["observations"])
    base = {"version": 2, "review_id": request["review_id"], "request_id": request["request_id"]}
    errors, lines = watch_errors(system, 60)
    try:
        bad = [
            ({**base, "states": [0, 1], "actions": [3]}, "one action per state"),
            ({**base, "states": [n], "actions": [3]}, "never shown"),
            ({**base, "request_id": request["request_id"] + 5, "states": [0], "actions": [3]}, "no label request"),
            ({**base, "states": [0], "actions": [7]}, "actions"),
        ]
        said = ["one action per state", "never shown", "no label request", "an action is 0 up, 1 down"]
        for (payload, _), words in zip(bad, said, strict=True):
            sent = lwm_ros(
                system, "pub", "/review/labels", json.dumps(payload), "--raw", "--kind", "labels", *signed(system)
            )
            # The sender hears why, in plain words, and exits non-zero.
            assert sent.returncode == 1 and words in sent.stderr, (sent.stdout, sent.stderr)
        want = [why for _, why in bad]

        def seen():
            got = [json.loads(x)["error"] for x in list(lines) if x.strip()]
            return all(any(w in g for g in got) for w in want) and got

        assert wait_for(seen, timeout=30), f"errors seen: {lines}"
        assert latched(system, "/planner/plan")["plan_id"] == plan["plan_id"]  # nothing changed
        fixed = {**base, "states": list(range(n)), "actions": [4] * n}
        sent = lwm_ros(system, "pub", "/review/labels", json.dumps(fixed), "--kind", "labels", *signed(system))
        assert sent.returncode == 0 and f"{n} label(s) for request" in sent.stdout, sent.stderr
        revised = wait_for(lambda: (p := latched(system, "/planner/plan"))["plan_id"] > plan["plan_id"] and p, 90)
        assert revised and revised["reason"] == "imitation" and revised["learning"]["labelled"] >= n
    finally:
        errors.terminate()
        errors.wait(timeout=30)


def test_the_planner_process_reads_no_world_model_weights(system):
    domain = system["env"]["ROS_DOMAIN_ID"]
    audit = system["tmp"] / "audit"

    def opened(module: str) -> str:
        f = audit / f"{node_pid(module, domain)}.txt"
        return f.read_text() if f.is_file() else ""

    served = SHIPPED[SYSTEM_WORLD_MODEL].name
    assert f"checkpoints/{served}/" in opened("lwm_nodes.world_model_node")  # the audit sees the world model
    planner = opened("lwm_nodes.planner_node")
    assert "checkpoints/policy-bc/" in planner  # it does load its policy
    assert not any(f"checkpoints/{m.directory}/" in planner for m in WORLD_MODELS)


def test_a_killed_node_is_restarted_and_the_person_is_told(system):
    """kill -9 of the world-model server: the launcher starts it again, it serves, and a person at
    the terminal hears that it stopped and started again, and what it says it serves now."""
    log = system["tmp"] / "logs" / "world_model.log"
    with terminal(system, "terminal-restart") as (_, said, log_path):
        time.sleep(2)  # it has heard the world-model server's diagnostics at least once
        os.kill(node_pid("lwm_nodes.world_model_node", system["env"]["ROS_DOMAIN_ID"]), signal.SIGKILL)
        assert wait_for(lambda: Path(log).read_text().count("READY") >= 2, timeout=60)
        ok = call(system, "/lwm/imagine", {"version": 1, "observation": OBS, "manual": MANUAL, "n": 1, "max_steps": 2})
        assert ok["ok"]
        notice = "NOTICE the world-model server stopped and started again; it says: serving"
        assert said(notice, timeout=30), log_path.read_text()[-2000:]


def test_only_a_trusted_reviewer_can_approve(system, tmp_path):
    """Anyone on the ROS domain can publish on /review/feedback. An approval of the plan under
    review that is unsigned, forged (signed with a key of the rogue's own under a trusted name) or
    signed by a reviewer the planner does not trust is refused on /lwm/errors and approves
    nothing; the same approval signed by a trusted reviewer is taken. The planner serves on."""
    from lwm_models import signing
    from lwm_models.ledger import Ledger

    assert call(system, "/env/reset", {"seed": 11})["ok"]
    plan = wait_for(lambda: (p := latched(system, "/planner/plan"))["review_id"].endswith(":11") and p, timeout=60)
    assert plan, "no plan for the reset episode"
    approve = {"version": 2, "review_id": plan["review_id"], "plan_id": plan["plan_id"], "decision": "approve"}
    rogue_keys = tmp_path / "rogue_keys.json"  # the rogue's own keys, not the launcher's
    signing.ensure_key_file(rogue_keys, ["mallory", "terminal"])
    errors, lines = watch_errors(system, 60)

    def taken() -> list[dict]:
        records = Ledger(system["tmp"] / "ledger.sqlite").history(plan["review_id"])
        return [r["payload"] for r in records if r["kind"] in ("feedback", "report")]

    try:
        rogues = [
            ([], "unsigned review_feedback (no reviewer named)"),
            (["--sign", "terminal", "--keys-file", str(rogue_keys)], "from reviewer 'terminal': bad signature"),
            (["--sign", "mallory", "--keys-file", str(rogue_keys)], "reviewer 'mallory', who is not trusted"),
        ]
        for extra, why in rogues:
            sent = lwm_ros(system, "pub", "/review/feedback", json.dumps(approve), "--kind", "review_feedback", *extra)
            assert sent.returncode == 1 and why in sent.stderr, sent.stderr

        def refused() -> list[str]:
            got = [json.loads(x) for x in list(lines) if x.strip()]
            reasons = [r["error"] for r in got if (r["node"], r["where"]) == ("planner", "/review/feedback")]
            return all(any(why in r for r in reasons) for _, why in rogues) and reasons

        assert wait_for(refused, timeout=30), f"errors seen: {lines}"
        assert all(
            r.startswith(("UnsignedPayload: /review/feedback:", "BadSignature:", "UntrustedReviewer:"))
            for r in refused()
        )
        assert taken() == [], "a refused approval reached the review"
        assert latched(system, "/planner/plan")["plan_id"] == plan["plan_id"]  # still under review

        # A person who joins the running system gets a key in the launcher's file: the planner,
        # which read the file at its start, reads it again when it first sees them.
        signing.ensure_key_file(system["tmp"] / "logs" / "reviewer_keys.json", ["dave"])
        sent = lwm_ros(
            system, "pub", "/review/feedback", json.dumps(approve), "--kind", "review_feedback", *signed(system, "dave")
        )
        assert sent.returncode == 0 and "approved: the agent now acts" in sent.stdout, sent.stderr
        feedback = wait_for(taken, timeout=30)
        assert feedback and feedback[0]["decision"] == "approve" and feedback[0]["reviewer"] == "dave"
        assert feedback[0]["plan_id"] == plan["plan_id"] and len(feedback[0]["signature"]) == 128
    finally:
        errors.terminate()
        errors.wait(timeout=30)


def test_the_terminal_review_shows_answers_refusals_and_takes_a_correction(system):
    """A person at the terminal: starts an episode (n SEED), sees a compact plan with a legend,
    is told why a correction is refused, and a correction of step 1 makes the next plan take it.
    The legend names both avatar symbols: the start shows '@', a board after the pick-up '&'."""
    with terminal(system, "terminal") as (type_line, said, log_path):
        type_line("n 21")
        assert said("episode newall-test:0:21 started"), log_path.read_text()[-2000:]
        assert said("=== plan ") and said("of review newall-test:0:21"), log_path.read_text()[-2000:]
        plan = wait_for(lambda: (p := latched(system, "/planner/plan"))["review_id"].endswith(":21") and p)
        text = log_path.read_text()
        assert "board: " in text and "actions: 0 up  1 down" in text and "steps: 1 " in text
        assert "@ you  & you, carrying the message" in text  # the legend names what later boards show
        type_line("c 99:3")
        assert said("REFUSED by the planner: step 99 is not in the plan"), log_path.read_text()[-2000:]
        wanted = (plan["actions"][0] + 2) % 5
        type_line(f"c 1:{wanted}")
        assert said(f"planner: corrections of plan {plan['plan_id']} taken"), log_path.read_text()[-2000:]
        revised = wait_for(lambda: (p := latched(system, "/planner/plan"))["plan_id"] > plan["plan_id"] and p)
        assert revised and revised["actions"][0] == wanted
        # This episode again, as a fresh review from the same first board.
        type_line("restart")
        assert said("episode newall-test:0:21#2 started again"), log_path.read_text()[-2000:]
        again = wait_for(lambda: (p := latched(system, "/planner/plan"))["review_id"].endswith(":21#2") and p)
        assert again and again["plan_id"] == 1 and again["observations"][0] == plan["observations"][0]
        assert again["actions"][0] == wanted  # the correction holds in the same state


def test_a_stop_ends_the_teaching_within_2_s_and_the_ledger_stays_consistent(system):
    """Teaching (online imitation) asks a person round after round; "stop" ends it at once: no
    label request after it, the policy learnt so far saved within 2 s, and a new plan from it."""
    assert call(system, "/env/reset", {"seed": 31})["ok"]
    plan = wait_for(lambda: (p := latched(system, "/planner/plan"))["review_id"].endswith(":31") and p, timeout=60)
    assert plan, "no plan for the reset episode"
    base = {"version": 2, "review_id": plan["review_id"], "plan_id": plan["plan_id"]}
    sent = lwm_ros(system, "pub", "/review/feedback", json.dumps({**base, "decision": "imitate", "rounds": 40}),
                   "--kind", "review_feedback", *signed(system))  # fmt: skip
    assert sent.returncode == 0 and "teaching started" in sent.stdout, sent.stderr
    request = wait_for(
        lambda: (r := latched(system, "/planner/label_request"))["review_id"] == plan["review_id"] and r, timeout=60
    )
    assert request and request["rounds"] == 40
    stop = json.dumps({**base, "decision": "stop"})
    sent = lwm_ros(system, "pub", "/review/feedback", stop, "--kind", "review_feedback", *signed(system))
    assert sent.returncode == 0 and "teaching stops now" in sent.stdout, sent.stderr
    revised = wait_for(lambda: (p := latched(system, "/planner/plan"))["plan_id"] > plan["plan_id"] and p, timeout=60)
    assert revised and revised["reason"] == "imitation" and revised["review_id"] == plan["review_id"]
    records = Ledger(system["tmp"] / "ledger.sqlite").history(plan["review_id"])
    at = next(i for i, r in enumerate(records) if r["kind"] == "feedback" and r["payload"]["decision"] == "stop")
    after = [r["kind"] for r in records[at + 1 :]]
    assert "label_request" not in after and after[:2] == ["policy", "plan"], after
    took = records[at + 1]["time"] - records[at]["time"]
    print(f"the teaching ended {took:.2f} s after the stop")
    assert took < 2.0, f"the teaching ended {took:.2f} s after the stop"
    later = json.dumps({**base, "plan_id": revised["plan_id"], "decision": "stop"})  # nothing to stop now
    again = lwm_ros(system, "pub", "/review/feedback", later, "--kind", "review_feedback", *signed(system))
    assert again.returncode == 1 and "nothing under way to stop" in again.stderr, again.stderr


def test_the_terminal_asks_about_an_unclear_manual_and_takes_the_answer(system):
    """A manual that leaves the robot's movement unclear: the terminal shows the agent's question,
    refuses a choice that is not offered in plain words, and `q N` sends the answer, which the
    world-model server holds and the next plan rests on."""
    with terminal(system, "terminal-question") as (type_line, said, log_path):
        before = latched(system, "/planner/plan")["plan_id"]
        type_line("m")
        for line in ("the plane chases you and it is deadly", "the ball has the secret message and runs away from you",
                     "there is a robot somewhere"):  # fmt: skip
            type_line(line)
        assert said("world-model server: manual version"), log_path.read_text()[-2000:]
        plan = wait_for(
            lambda: (p := latched(system, "/planner/plan"))["plan_id"] > before and p.get("questions") and p
        )
        assert plan, latched(system, "/planner/plan")
        asked = plan["questions"][0]
        assert asked["entity"] == "robot" and asked["field"] == "movement", asked
        assert said("the agent is not sure (") and said(asked["text"]), log_path.read_text()[-2000:]
        type_line("q 7")
        assert said("not sent: answer with one choice number: q 1 to q 3"), log_path.read_text()[-2000:]
        choice = 1 + [c["value"] for c in asked["choices"]].index("immovable")
        type_line(f"q {choice}")
        assert said("it holds what you answered: the robot stays where it is"), log_path.read_text()[-2000:]
        revised = wait_for(lambda: (p := latched(system, "/planner/plan"))["plan_id"] > plan["plan_id"] and p)
        assert revised and {"entity": "robot", "field": "movement", "value": "immovable"} in revised["facts"]
        robot = next(e for e in revised["roles"] if e["identity"] == "robot")
        assert robot["movement"] == "stays put" and robot["movement_p"] == 1.0
        assert status(system)["facts"] == revised["facts"]


def test_a_correction_survives_a_killed_planner(system):
    """kill -9 of the planner after a person's correction: the restarted planner resumes the review
    from the ledger with the correction kept, so a plan it imagines afterwards still takes it, and
    the correction is in the ledger once."""
    from lwm_models.ledger import Ledger

    assert call(system, "/env/reset", {"seed": 33})["ok"]
    plan = wait_for(lambda: (p := latched(system, "/planner/plan"))["review_id"].endswith(":33") and p, timeout=90)
    assert plan, "no plan for the reset episode"
    wanted = (plan["actions"][0] + 2) % 5
    base = {"version": 2, "review_id": plan["review_id"]}
    fix = {
        **base,
        "plan_id": plan["plan_id"],
        "decision": "corrections",
        "corrections": [{"step": 1, "action": wanted}],
    }
    sent = lwm_ros(system, "pub", "/review/feedback", json.dumps(fix), "--kind", "review_feedback", *signed(system))
    assert sent.returncode == 0, sent.stderr
    revised = wait_for(lambda: (p := latched(system, "/planner/plan"))["plan_id"] > plan["plan_id"] and p, timeout=60)
    assert revised and revised["actions"][0] == wanted

    log = system["tmp"] / "logs" / "planner.log"
    ready = log.read_text().count("READY")
    os.kill(node_pid("lwm_nodes.planner_node", system["env"]["ROS_DOMAIN_ID"]), signal.SIGKILL)
    assert wait_for(lambda: log.read_text().count("READY") > ready, timeout=90), log.read_text()[-2000:]
    assert wait_for(lambda: f"review {plan['review_id']} resumed from the ledger" in log.read_text(), timeout=60)
    reject = {**base, "plan_id": revised["plan_id"], "decision": "reject"}
    sent = wait_for(
        lambda: (s := lwm_ros(system, "pub", "/review/feedback", json.dumps(reject), "--kind", "review_feedback",
                              *signed(system))).returncode == 0 and s, timeout=60)  # fmt: skip
    assert sent, "the restarted planner never took the reject"
    again = wait_for(lambda: (p := latched(system, "/planner/plan"))["plan_id"] > revised["plan_id"] and p, timeout=60)
    assert again and again["actions"][0] == wanted, "the restarted planner lost the correction"
    feedback = [r["payload"] for r in Ledger(system["tmp"] / "ledger.sqlite").history(plan["review_id"])
                if r["kind"] == "feedback"]  # fmt: skip
    assert [f["decision"] for f in feedback] == ["corrections", "reject"]


def test_a_manual_a_correction_and_labels_survive_kill_9_of_every_node(system):
    """A person's manual, a correction and a round of labels, then kill -9 of the world-model
    server, the environment and the planner in turn: each comes back, the served manual is the
    person's (its version unchanged, the ledger's last), the planner's plans still take the
    correction, each answer is in the ledger once, and undo over ROS still takes the labels back."""
    env = system["env"]
    assert call(system, "/env/reset", {"seed": 44})["ok"]
    plan = wait_for(lambda: (p := latched(system, "/planner/plan"))["review_id"].endswith(":44") and p, timeout=90)
    assert plan, "no plan for the reset episode"
    base = {"version": 2, "review_id": plan["review_id"]}

    def send(topic: str, kind: str, payload: dict) -> None:
        sent = wait_for(lambda: (s := lwm_ros(system, "pub", topic, json.dumps(payload), "--kind", kind,
                                              *signed(system))).returncode == 0 and s, timeout=60)  # fmt: skip
        assert sent, f"{topic} never took {payload}"

    def next_plan(after: dict) -> dict:
        p = wait_for(lambda: (q := latched(system, "/planner/plan"))["plan_id"] > after["plan_id"] and q, timeout=90)
        assert p, f"no plan after plan {after['plan_id']}"
        return p

    mine = list(reversed(MANUAL2))  # a manual of the person's own, new to this server
    send("/feedback/manual", "manual", {"version": 2, "descriptions": mine})
    plan = wait_for(lambda: (p := latched(system, "/planner/plan"))["manual"] == mine and p, timeout=90)
    assert plan, "no plan under the person's manual"
    version = status(system)["manual_version"]
    wanted = (plan["actions"][0] + 2) % 5
    fix = [{"step": 1, "action": wanted}]
    send("/review/feedback", "review_feedback", {**base, "plan_id": plan["plan_id"], "decision": "corrections",
                                                 "corrections": fix})  # fmt: skip
    plan = next_plan(plan)
    assert plan["actions"][0] == wanted
    send(
        "/review/feedback", "review_feedback", {**base, "plan_id": plan["plan_id"], "decision": "imitate", "rounds": 1}
    )
    request = wait_for(lambda: (r := latched(system, "/planner/label_request"))["review_id"] == base["review_id"] and r)
    assert request, "no label request"
    n = len(request["observations"])
    send("/review/labels", "labels",
         {**base, "request_id": request["request_id"], "states": list(range(n)), "actions": [4] * n})  # fmt: skip
    plan = next_plan(plan)
    assert plan["reason"] == "imitation" and plan["learning"]["imitation_rounds"] == 1

    for module, log in (("world_model_node", "world_model"), ("env_node", "env"), ("planner_node", "planner")):
        text = system["tmp"] / "logs" / f"{log}.log"
        ready = text.read_text().count("READY")
        os.kill(node_pid(f"lwm_nodes.{module}", env["ROS_DOMAIN_ID"]), signal.SIGKILL)
        assert wait_for(lambda: text.read_text().count("READY") > ready, timeout=90), text.read_text()[-2000:]  # noqa: B023
    served = wait_for(lambda: (s := status(system))["manual"] == mine and s, timeout=30)
    assert served and served["manual_version"] == version, "the restarted server serves another manual"
    assert wait_for(lambda: f"review {base['review_id']} resumed from the ledger" in
                    (system["tmp"] / "logs" / "planner.log").read_text(), timeout=60)  # fmt: skip

    send("/review/feedback", "review_feedback", {**base, "plan_id": plan["plan_id"], "decision": "reject"})
    plan = next_plan(plan)
    assert plan["actions"][0] == wanted and plan["manual"] == mine and plan["learning"]["imitation_rounds"] == 1
    send("/review/feedback", "review_feedback", {**base, "plan_id": plan["plan_id"], "decision": "undo"})
    plan = next_plan(plan)
    assert plan["reason"] == "undo" and plan["learning"]["imitation_rounds"] == 0
    assert plan["learning"]["corrections"] == 1 and plan["actions"][0] == wanted  # the correction stays

    history = Ledger(system["tmp"] / "ledger.sqlite").history(base["review_id"])
    feedback = [r["payload"]["decision"] for r in history if r["kind"] == "feedback"]
    assert feedback == ["corrections", "imitate", "reject", "undo"]
    assert [r["kind"] for r in history].count("labels") == 1
    manuals = [r["payload"] for r in history if r["kind"] == "manual"]
    assert manuals[-1]["descriptions"] == mine and manuals[-1]["manual_version"] == version
