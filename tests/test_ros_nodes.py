"""The ROS 2 nodes across real processes: the launcher starts the environment and simulator nodes
(on the shipped EMMA-LWM), and the `lwm ros` command line (its own process) talks to them over
Fast DDS on localhost."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("lwm_interfaces")


MANUAL = [
    "the plane is the deadly enemy and it chases you.",
    "the ball has the secret message and runs away from you.",
    "the robot is the goal and never moves.",
]
OBS = [[2, 2, 7], [10, 7, 2], [11, 7, 7], [15, 2, 2]]


@pytest.fixture(scope="module")
def system(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ros")
    env = {
        **os.environ,
        "ROS_DOMAIN_ID": str(1 + os.getpid() % 100),
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


def call(system, service: str, payload: dict | str) -> dict:
    text = payload if isinstance(payload, str) else json.dumps(payload)
    proc = lwm_ros(system, "call", service, text, "--raw")
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def status(system) -> dict:
    proc = lwm_ros(system, "echo", "/lwm/status", "--latched", "--count", "1", "--timeout", "10")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def wait_for(predicate, timeout: float = 15.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.3)
    return predicate()


def test_graph_lists_the_nodes_and_services(system):
    # Graph discovery of a fresh process took over the default 1 s once in CI on a loaded machine.
    nodes = lwm_ros(system, "nodes", "--settle", "3").stdout.split()
    assert "/messenger_env" in nodes and "/lwm_simulator" in nodes
    services = lwm_ros(system, "services", "--settle", "3").stdout
    assert "/lwm/imagine [lwm_interfaces/srv/Imagine]" in services and "/env/step" in services


def test_imagine_uses_the_environment_manual_then_the_feedback(system):
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
        json.dumps({"version": 1, "descriptions": MANUAL, "source": "human"}),
        "--latched",
        "--kind",
        "manual",
    )
    assert pub.returncode == 0, pub.stderr
    st = wait_for(lambda: (s := status(system))["manual_source"] == "human" and s)
    assert st["manual"] == MANUAL and st["manual_version"] >= 2
    second = call(
        system, "/lwm/imagine", {"version": 1, "observation": OBS, "actions": [[1, 1, 3]], "max_steps": 3, "seed": 5}
    )
    assert second["manual"] == MANUAL and second["manual_version"] == st["manual_version"]
    assert second["trajectories"][0]["confidence"] != first["trajectories"][0]["confidence"]


def test_environment_reset_and_step(system):
    reset = call(system, "/env/reset", {"seed": 3})
    assert reset["ok"] and reset["state"]["t"] == 0
    step = call(system, "/env/step", {"action": 3})
    assert step["ok"] and step["state"]["t"] == 1
    bad = call(system, "/env/step", {"action": 9})
    assert not bad["ok"] and "0..4" in bad["error"]


def latched(system, topic: str) -> dict:
    proc = lwm_ros(system, "echo", topic, "--latched", "--count", "1", "--timeout", "20")
    assert proc.returncode == 0, f"nothing latched on {topic}"
    return json.loads(proc.stdout.strip().splitlines()[-1])


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
        ("lwm_simulator", "/feedback/manual"),
        ("lwm_simulator", "/env/manual"),
        ("planner", "/env/manual"),
        ("planner", "/env/state"),
        ("human_feedback", "/env/state"),
        ("human_feedback", "/planner/plan"),
        ("human_feedback", "/planner/report"),
        ("planner", "/review/feedback"),
        ("lwm_simulator", "/lwm/imagine"),
        ("messenger_env", "/env/reset"),
        ("messenger_env", "/env/step"),
    }
    errors = subprocess.Popen(
        [sys.executable, "-m", "lwm_models.cli.main", "ros", "echo", "/lwm/errors", "--timeout", "90"],
        stdout=subprocess.PIPE,
        text=True,
        env=system["env"],
    )
    try:
        time.sleep(2.0)
        plan = latched(system, "/planner/plan")
        for topic, payload in [
            ("/feedback/manual", '{"version": 1, "descriptions": ["just one"]}'),
            ("/env/manual", "{not json"),
            ("/env/state", '{"version": 1, "t": "zero"}'),
            ("/planner/plan", "[]"),
            ("/planner/report", '{"version": 1}'),
            # Valid JSON for the schema, but step 99 is not in the plan: the agent rejects it.
            (
                "/review/feedback",
                json.dumps(
                    {
                        "version": 1,
                        "review_id": plan["review_id"],
                        "plan_id": plan["plan_id"],
                        "decision": "corrections",
                        "corrections": [{"step": 99, "action": 1}],
                    }
                ),
            ),
        ]:
            readers = {"/env/manual": 2, "/env/state": 2}.get(topic, 1)
            assert lwm_ros(system, "pub", topic, payload, "--raw", "-w", str(readers), "--wait", "10").returncode == 0
        bad = call(system, "/lwm/imagine", "{not json")
        assert not bad["ok"] and "not JSON" in bad["error"]
        bad = call(system, "/env/reset", "[1, 2]")
        assert not bad["ok"]
        bad = call(system, "/env/step", '{"action": "up"}')
        assert not bad["ok"]

        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.extend(errors.stdout), daemon=True)
        reader.start()

        def reports() -> list[dict]:
            return [json.loads(line) for line in list(lines) if line.strip()]

        wait_for(lambda: {(r["node"], r["where"]) for r in reports()} >= expected, timeout=60)
        got = {(r["node"], r["where"]) for r in reports()}
        assert got >= expected, f"missing error reports: {sorted(expected - got)}"
        assert all(r["error"] for r in reports())

        # Everyone still serves: the services answer, the planner takes a corrected feedback
        # for the same plan and publishes the next plan, the human node prints it.
        ok = call(system, "/lwm/imagine", {"version": 1, "observation": OBS, "n": 2, "max_steps": 2})
        assert ok["ok"] and len(ok["trajectories"]) == 2
        assert call(system, "/env/reset", {"seed": 3})["ok"]
        assert call(system, "/env/step", {"action": 4})["ok"]
        plan = wait_for(lambda: (p := latched(system, "/planner/plan"))["review_id"].endswith(":3") and p, timeout=60)
        assert plan, "no plan for the reset episode"
        fix = {
            "version": 1,
            "review_id": plan["review_id"],
            "plan_id": plan["plan_id"],
            "decision": "corrections",
            "corrections": [{"step": 1, "action": (plan["actions"][0] + 1) % 5}],
        }
        assert lwm_ros(system, "pub", "/review/feedback", json.dumps(fix), "--kind", "review_feedback").returncode == 0
        revised = wait_for(
            lambda: (p := latched(system, "/planner/plan"))["plan_id"] > plan["plan_id"] and p, timeout=60
        )
        assert revised and revised["review_id"] == plan["review_id"]
        log = system["tmp"] / "human_node.log"
        assert wait_for(lambda: f"=== plan {revised['plan_id']} " in log.read_text(), timeout=30)
        assert human.poll() is None
    finally:
        errors.terminate()
        assert errors.wait(timeout=30) == 130
        human.send_signal(signal.SIGINT)
        human.wait(timeout=30)
    assert human.returncode == 0


def node_pid(module: str, domain: str) -> int:
    """The pid of a node process of the given ROS domain (other tests' systems may be running)."""
    for pid in subprocess.run(["pgrep", "-f", module], capture_output=True, text=True).stdout.split():
        try:
            environ = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if f"ROS_DOMAIN_ID={domain}".encode() in environ:
            return int(pid)
    raise AssertionError(f"no {module} process in domain {domain}")


def test_a_killed_node_is_restarted(system):
    log = system["tmp"] / "logs" / "simulator.log"
    os.kill(node_pid("lwm_nodes.simulator_node", system["env"]["ROS_DOMAIN_ID"]), signal.SIGKILL)
    assert wait_for(lambda: Path(log).read_text().count("READY") >= 2, timeout=60)
    ok = call(system, "/lwm/imagine", {"version": 1, "observation": OBS, "manual": MANUAL, "n": 1, "max_steps": 2})
    assert ok["ok"]


def start_scripted(tmp_path: Path, domain_offset: int) -> tuple[subprocess.Popen, dict, Path]:
    """The launcher with the scripted human, in its own ROS domain; returns (process, env, ledger)."""
    env = {
        **os.environ,
        "ROS_DOMAIN_ID": str(1 + (os.getpid() + domain_offset) % 100),
        "ROS_LOG_DIR": str(tmp_path / "roslog"),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
    }
    ledger = tmp_path / "ledger.sqlite"
    cmd = [
        sys.executable,
        "-m",
        "lwm_nodes.launcher",
        "--scripted",
        "--quiet",
        "--log-dir",
        str(tmp_path / "logs"),
        "--ledger",
        str(ledger),
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    return proc, env, ledger


def test_scripted_review_loop_end_to_end(tmp_path):
    proc, _, ledger = start_scripted(tmp_path, 50)
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, out[-3000:]
    assert "human finished" in out
    summary = [line for line in (tmp_path / "logs" / "human.log").read_text().splitlines() if "SUMMARY" in line]
    assert summary and "real return" in summary[0]
    shown = subprocess.run(
        [sys.executable, "-m", "lwm_models.cli.main", "ledger", "show", "--path", str(ledger)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    kinds = [line.split()[2] for line in shown.stdout.splitlines()[1:]]
    assert kinds[0] == "manual" and kinds[1] == "plan" and "feedback" in kinds and kinds[-1] == "executed"


def test_planner_killed_mid_review_resumes_from_the_ledger(tmp_path):
    proc, env, ledger_path = start_scripted(tmp_path, 25)
    from lwm_models.ledger import Ledger

    def first_plan_recorded():
        if not ledger_path.is_file():
            return False
        return any(r["kind"] == "plan" for r in Ledger(ledger_path).history())

    assert wait_for(first_plan_recorded, timeout=180)
    os.kill(node_pid("lwm_nodes.planner_node", env["ROS_DOMAIN_ID"]), signal.SIGKILL)
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, out[-3000:]
    assert "planner exited with -9; restart 1" in out
    records = Ledger(ledger_path).history()
    plan_ids = [r["payload"]["plan_id"] for r in records if r["kind"] == "plan"]
    assert plan_ids == sorted(set(plan_ids)), f"a plan was recorded twice: {plan_ids}"
    assert [r["kind"] for r in records].count("report") == 1
    assert sum(r["kind"] == "manual" and r["payload"]["source"] == "env" for r in records) == 1
    assert "resumed from the ledger" in (tmp_path / "logs" / "planner.log").read_text()
