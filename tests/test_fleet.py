"""A fleet under review: several agents, each in its ROS namespace, sharing one world-model server.

The server keeps a manual per agent: a manual goes to one agent or to every agent, and each
agent's imagination reads its own. Tested on the ROS-free server, on the launcher's node specs,
and across real processes (one fleet of two agents started by the launcher)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from game_fixtures import MANUAL, OBS

from lwm_models.world.model_server import RequestError

pytestmark = pytest.mark.system

OTHER = [
    "the plane is the messenger and it flees from you.",
    "the robot does not move, it is the goal.",
    "the ball comes at you, it is deadly.",
]


@pytest.fixture()
def fleet_server(tmp_path):
    import torch

    from lwm_models.world.frozen_text import FrozenTextEncoder
    from lwm_models.world.model_server import WorldModelServer

    torch.set_num_threads(1)
    return WorldModelServer(
        encoder=FrozenTextEncoder(), state_path=tmp_path / "state.json", agents=("agent1", "agent2")
    )


def imagine(server, agent: str | None) -> dict:
    request = {"version": 1, "observation": np.asarray(OBS).tolist(), "n": 2, "max_steps": 3, "seed": 0}
    if agent is not None:
        request["agent"] = agent
    return server.handle(request)


def test_a_fleet_manual_reaches_every_agent_and_an_agent_manual_only_its_agent(fleet_server):
    s = fleet_server
    assert s.set_fleet_manual(MANUAL, "human") == {"agent1": (1, True), "agent2": (1, True)}
    assert s.set_fleet_manual(MANUAL, "human") == {"agent1": (1, False), "agent2": (1, False)}
    assert s.set_manual(OTHER, "human", "agent2") == (2, True)
    one, two = imagine(s, "agent1"), imagine(s, "agent2")
    assert (one["manual_version"], one["manual"]) == (1, MANUAL)
    assert (two["manual_version"], two["manual"]) == (2, OTHER)
    # A request that names no agent is the first agent's: the single-agent system's behaviour.
    assert imagine(s, None)["manual"] == MANUAL
    assert s.status("agent2")["agent"] == "agent2" and s.status("agent2")["manual_version"] == 2
    with pytest.raises(RequestError, match="serves no agent 'agent3'.*'agent1', 'agent2'"):
        imagine(s, "agent3")


def test_an_agents_environment_manual_does_not_replace_a_persons_manual_of_the_same_game(fleet_server):
    s = fleet_server
    s.take_env_manual(MANUAL, "newall-test:0:0", "agent1")
    s.take_env_manual(MANUAL, "newall-test:0:1", "agent2")
    s.set_fleet_manual(OTHER, "human")
    assert s.take_env_manual(MANUAL, "newall-test:0:2", "agent2") == (2, False)  # same game: the person's stays
    assert s.take_env_manual(MANUAL, "newall-test:1:0", "agent2") == (3, True)  # another game: its own
    assert s.state("agent1").manual == OTHER and s.state("agent2").manual == MANUAL


def test_each_agents_manual_and_version_survive_a_restart_and_an_old_state_file_is_the_first_agents(
    fleet_server, tmp_path
):
    from lwm_models.world.model_server import WorldModelServer

    s = fleet_server
    s.set_fleet_manual(MANUAL, "human")
    s.set_manual(OTHER, "human", "agent2")
    again = WorldModelServer(encoder=s.encoder, state_path=tmp_path / "state.json", agents=("agent1", "agent2"))
    assert (again.state("agent1").version, again.state("agent1").manual) == (1, MANUAL)
    assert (again.state("agent2").version, again.state("agent2").manual) == (2, OTHER)
    assert imagine(again, "agent2")["manual_version"] == 2

    old = tmp_path / "old.json"  # the single-agent file of runs before fleets
    old.write_text(json.dumps({"manual": OTHER, "version": 7, "source": "human", "game": "newall-test:0"}))
    single = WorldModelServer(encoder=s.encoder, state_path=old)
    assert (single.manual_version, single.manual, single.game) == (7, OTHER, "newall-test:0")


def test_the_launcher_puts_each_agent_in_its_namespace_with_its_seed_ledger_and_reviewer(tmp_path):
    from lwm_nodes.launcher import CONFIG_DIR, default_nodes, fleet

    nodes = default_nodes("scripted", {"env": {"seed": "5"}, "human": {"language": "true"}})
    specs = {n.name: n for n in fleet(nodes, 3, 5, tmp_path)}
    assert sorted(specs) == sorted(
        ["world_model"] + [f"agent{i}/{r}" for i in (1, 2, 3) for r in ("env", "planner", "human")]
    )
    assert specs["world_model"].params["agents"] == "[agent1,agent2,agent3]" and not specs["world_model"].namespace
    assert [specs[f"agent{i}/env"].params["seed"] for i in (1, 2, 3)] == ["5", "6", "7"]
    assert specs["agent2/planner"].params["ledger"] == str(tmp_path / "agent2" / "ledger.sqlite")
    command = specs["agent3/env"].command()
    assert command[3:8] == [
        "--ros-args",
        "-r",
        "__ns:=/agent3",
        "--params-file",
        str(CONFIG_DIR / "messenger_env.yaml"),
    ]
    seed = command.index("seed:=7")  # after the file: it overrides the file's seed
    assert command[seed - 1] == "-p" and seed > command.index(str(CONFIG_DIR / "messenger_env.yaml"))
    # The first reviewer speaks to the whole fleet; the others review without speaking.
    assert specs["agent1/human"].params["manual_topic"] == "/feedback/manual"
    assert "language" not in specs["agent2/human"].params and "manual_topic" not in specs["agent2/human"].params
    assert all(specs[f"agent{i}/human"].final for i in (1, 2, 3))


# ---------------------------------------------------------------------------------------- ROS
def _ros(env: dict, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "lwm_models.cli.main", "ros", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
    )


def _latched(env: dict, topic: str) -> dict:
    proc = _ros(env, "echo", topic, "--latched", "--count", "1", "--timeout", "15")
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _wait(predicate, timeout: float):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if value := predicate():
            return value
        time.sleep(0.5)
    return predicate()


def test_two_agents_share_one_world_model_server_and_one_manual_replans_both(tmp_path):
    """`--agents 2`: each agent's nodes in /agent1 and /agent2, one world-model server. A manual on
    /agent2/feedback/manual changes agent2's alone; one on /feedback/manual re-plans both agents,
    each under the new version, and each planner records it in its own ledger."""
    pytest.importorskip("rclpy")
    from lwm_nodes import domains

    from lwm_models.ledger import Ledger

    env = {
        **os.environ,
        "ROS_DOMAIN_ID": str(domains.claim()),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "ROS_LOG_DIR": str(tmp_path / "roslog"),
    }
    logs = tmp_path / "logs"
    cmd = [sys.executable, "-m", "lwm_nodes.launcher", "--agents", "2", "--no-human", "--quiet", "--log-dir", str(logs)]
    proc = subprocess.Popen(
        [*cmd, "--iterations", "1", "--futures", "2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    try:
        for line in proc.stdout:
            if "nodes ready" in line or "did not become ready" in line:
                break
        assert proc.poll() is None, "launcher died"
        nodes = _ros(env, "nodes", "--settle", "3").stdout.split()
        assert {"/agent1/planner", "/agent2/planner", "/agent1/messenger_env", "/lwm_world_model"} <= set(nodes)

        def plans(i: int) -> list[dict]:
            path = logs / f"agent{i}" / "ledger.sqlite"
            if not path.is_file():
                return []
            book = Ledger(path, read_only=True)
            try:
                return [r["payload"] for r in book.history() if r["kind"] == "plan"]
            finally:
                book.close()

        assert _wait(lambda: plans(1) and plans(2), 240), "each agent plans under its environment's manual"
        # Every node reports its health on /diagnostics; the server, its batches and each manual.
        report = _ros(env, "diagnostics", "--seconds", "3", "--json")
        assert report.returncode == 0, report.stderr
        health = {h["node"]: h for h in map(json.loads, report.stdout.splitlines())}
        assert {"/agent1/planner", "/agent2/planner", "/agent2/messenger_env", "/lwm_world_model"} <= set(health)
        server = health["/lwm_world_model"]
        assert server["level"] == "OK" and int(server["calls"]) > 0 and float(server["latency p99 ms"]) > 0
        assert "manual version of agent2" in server and "phase" in health["/agent1/planner"]
        first = [_latched(env, f"/agent{i}/lwm/status") for i in (1, 2)]
        assert [s["agent"] for s in first] == ["agent1", "agent2"] and all(s["manual_source"] == "env" for s in first)

        sign = ["--kind", "manual", "--sign", "terminal", "--keys-file", str(logs / "reviewer_keys.json")]
        one = _ros(env, "pub", "/agent2/feedback/manual", json.dumps({"descriptions": OTHER}), *sign)
        assert one.returncode == 0 and "manual taken for agent2" in one.stdout, one.stdout + one.stderr
        assert _latched(env, "/agent1/lwm/status")["manual_version"] == first[0]["manual_version"]
        assert _latched(env, "/agent2/lwm/status")["manual"] == OTHER

        everyone = _ros(env, "pub", "/feedback/manual", json.dumps({"descriptions": MANUAL}), *sign)
        assert everyone.returncode == 0 and "agent1" in everyone.stdout and "agent2" in everyone.stdout, everyone.stdout
        for i in (1, 2):
            replanned = _wait(
                lambda i=i: [p for p in plans(i) if p["reason"] == "manual" and p["manual"] == MANUAL], 240
            )
            assert replanned, f"agent{i} did not re-plan under the fleet's manual"
        # One server answered every agent: its log names both, and each agent's env served its own seed.
        served = (logs / "world_model.log").read_text()
        assert "serving agent1, agent2" in served
        assert [p["review_id"] for p in (plans(1)[0], plans(2)[0])] == ["newall-test:0:0", "newall-test:0:1"]
    finally:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, out[-3000:]
    assert Path(logs / "agent1.planner.log").is_file()
