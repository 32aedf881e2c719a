"""The system under load and abuse, on the real multi-process system (loopback only, bounded).

    .venv/bin/python benchmarks/ros_stress.py load [--clients 8] [--calls 1000] [--baseline-calls 200]
    .venv/bin/python benchmarks/ros_stress.py paths [--pairs 3] [--clients 8] [--calls 500]
    .venv/bin/python benchmarks/ros_stress.py malformed [--payloads 10000]
    .venv/bin/python benchmarks/ros_stress.py kill [--iterations 6]
    .venv/bin/python benchmarks/ros_stress.py shutdown [--clients 8]

load: `/lwm/imagine` from one client process, then from N client processes at once (each call:
one trajectory replaying 4 actions, padded with "stay" to 32 steps, until the imagined episode
ends; the one client's calls are a random sample of the N clients'), against the launcher's
system without a human (environment, world-model server, planner). Prints calls/s, imagined steps/s and
p50/p99 latency of both, their ratios (target: N=8 clients get >= 5x the throughput of one,
p99 < 1 s, 0 failures), and the latency of `/env/reset` probed during the load (the other nodes
still answer).

paths: the same load of N clients on the system started with the reference decoding path
(`LWM_DECODING=reference`, every process) and on the default path, in alternating launches, a
pair at a time: each pair's calls/s, p50/p99 and ratio, and the median over the pairs (target of
issue 32: >= 2x the reference's calls/s with a p99 under 200 ms). This machine's speed moves by
tens of percent between minutes, so a pair is two launches one after the other and the median of
several pairs is the figure.

malformed: payloads that are not valid messages (invalid JSON, wrong types, 1 MB strings, deeply
nested JSON, NaN, out-of-range and 10,000-step action lists, unicode) spread over every topic and
service the nodes read, paced so that none is dropped by a queue. Target: 0 crashes (every node
still running and answering), every payload reported on /lwm/errors (topics) or answered with an
error (services), and the nodes' memory before and after.

kill: `kill -9` of each node in turn (world-model server, planner, environment, human) during a scripted
review. Target: the launcher restarts each, the review resumes and ends with its summary, SQLite's
integrity_check is ok, and no ledger record is lost or doubled (plans numbered without gaps or
repeats, one decision per plan and decision, one label answer per request, one report).

shutdown: SIGTERM to the launcher while N clients keep calling /lwm/imagine (and a scripted
review is under way): each node's exit, timed by the launcher. Target: every node within 2 s.

Each part starts its own system, in a ROS domain no other run on this machine holds, and stops it
at the end.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import textwrap
import threading
import time
from pathlib import Path

import numpy as np

from lwm_models.cli.args import positive_int
from lwm_models.run_dirs import LEDGER_FILE

if "ROS_DOMAIN_ID" not in os.environ:  # one no other run on this machine holds
    from lwm_nodes import domains

    os.environ["ROS_DOMAIN_ID"] = str(domains.claim())
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

ROOT = Path(__file__).resolve().parent.parent
OBS = [[2, 2, 7], [10, 7, 2], [11, 7, 7], [15, 2, 2]]


def imagine_request(i: int) -> dict:
    return {"version": 1, "observation": OBS, "actions": [[i % 5, 3, 1, 4]], "max_steps": 32, "seed": i}


# A client process: waits for the service and for the start time, makes its calls one after
# another (the first `calls` of a fixed random order of the first `population` requests, so a
# sample of another load's requests), prints one JSON line with its latencies, failures
# and the steps imagined. It ends with os._exit: a Fast DDS participant being destroyed once
# spun for 20 minutes in one of 8 clients (DomainParticipant::set_listener, seen in gdb).
CLIENT = textwrap.dedent(
    r"""
    import json, os, sys, time
    import numpy as np
    import rclpy
    from lwm_interfaces.srv import Json
    from lwm_nodes.common import ros_environment
    from lwm_nodes.ros_cli import BackgroundSpin
    sys.path.insert(0, sys.argv[4])
    from ros_stress import imagine_request
    service, calls, start_at, population = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[5])
    order = np.random.default_rng(0).permutation(population) if population > calls else np.arange(calls)
    ros_environment(); rclpy.init()
    node = rclpy.create_node(f"stress_client_{int(time.time() * 1e6) % 10**9}")
    spin = BackgroundSpin(node)
    client = node.create_client(Json, service)
    ok = client.wait_for_service(timeout_sec=60)
    while time.time() < start_at:
        time.sleep(0.005)
    lat, fail, batched, steps = [], 0, [], 0
    first = time.time()
    for i in order[: calls if ok else 0]:
        text = json.dumps(imagine_request(int(i)))
        t = time.perf_counter()
        res = client.call(Json.Request(request=text), timeout_sec=30)
        lat.append(time.perf_counter() - t)
        answer = json.loads(res.response) if res is not None else {"ok": False}
        fail += not answer.get("ok")
        batched.append(answer.get("batched", 1))
        steps += sum(len(tr["actions"]) for tr in answer.get("trajectories", []))
    out = {"latencies": lat, "failures": fail + (0 if ok else calls), "batched": batched, "first": first}
    print(json.dumps({**out, "steps": steps, "last": time.time()}), flush=True)
    os._exit(0)
    """
)


class System:
    """The launcher's system (no human) in a temporary directory, stopped on exit."""

    def __init__(self, extra: list[str] | None = None, human: str = "--no-human", restarts: int = 0) -> None:
        self.dir = Path(tempfile.mkdtemp(prefix="lwm-stress-"))
        self.ledger = self.dir / LEDGER_FILE
        cmd = [sys.executable, "-m", "lwm_nodes.launcher", human, "--quiet", "--max-restarts", str(restarts)]
        cmd += ["--log-dir", str(self.dir), "--ledger", str(self.ledger), *(extra or [])]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT)
        self.lines: list[str] = []
        self.ready = threading.Event()
        threading.Thread(target=self._pump, daemon=True).start()
        if not self.ready.wait(180):
            self.stop()
            raise SystemExit(f"the system did not start: {''.join(self.lines[-20:])}")

    def _pump(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line)
            if "nodes ready" in line:
                self.ready.set()

    def node_pids(self) -> dict[str, int]:
        """PID of each node process (the launcher's children), by node module, and of the
        world-model server's batch worker processes (its children: "worker", "worker 2", ...)."""
        pids = {}
        for pid, cmd in _children(self.proc.pid):
            for name in ("env_node", "simulator_node", "planner_node", "human_node"):
                if f"lwm_nodes.{name}" in cmd:
                    pids[name.removesuffix("_node")] = pid
        if "world_model" in pids:
            workers = [pid for pid, cmd in _children(pids["world_model"]) if "lwm_models.world.imagine_worker" in cmd]
            pids.update({"worker" if i == 0 else f"worker {i + 1}": pid for i, pid in enumerate(sorted(workers))})
        return pids

    def stop(self) -> int:
        self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()


def _children(pid: int) -> list[tuple[int, str]]:
    out = subprocess.run(["pgrep", "-P", str(pid), "-a"], capture_output=True, text=True).stdout
    return [(int(p), cmd) for p, _, cmd in (line.partition(" ") for line in out.splitlines())]


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return math.nan


def run_clients(
    n: int, calls: int, population: int = 0, start_at: float | None = None
) -> tuple[list[float], int, float, list[int], int]:
    """n client processes making `calls` calls each, started together at `start_at` (default: in
    8 s, when every client has discovered the service); (latencies, failures, wall-clock seconds
    of the whole load, batch sizes, trajectory steps imagined)."""
    start_at = start_at or time.time() + 8.0
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                "-c",
                CLIENT,
                "/lwm/imagine",
                str(calls),
                str(start_at),
                str(Path(__file__).parent),
                str(population),
            ],
            stdout=subprocess.PIPE,
            text=True,
        )
        for _ in range(n)
    ]
    results = [json.loads(p.communicate(timeout=3600)[0].strip().splitlines()[-1]) for p in procs]
    wall = max(r["last"] for r in results) - min(r["first"] for r in results)  # calls only, not start-up
    lat = [x for r in results for x in r["latencies"]]
    batched = [b for r in results for b in r["batched"]]
    return lat, sum(r["failures"] for r in results), wall, batched, sum(r["steps"] for r in results)


def probe_env(stop: threading.Event, out: list[float], start_at: float = 0.0) -> None:
    """/env/reset from this process every 0.5 s while the load runs (from `start_at`: not while
    the client processes start, which takes both cores for a few seconds)."""
    import rclpy
    from lwm_interfaces.srv import Json
    from lwm_nodes.common import ros_environment
    from lwm_nodes.ros_cli import BackgroundSpin

    ros_environment()
    rclpy.init()
    node = rclpy.create_node("stress_probe")
    spin = BackgroundSpin(node)
    client = node.create_client(Json, "/env/reset")
    client.wait_for_service(timeout_sec=60)
    stop.wait(max(0.0, start_at - time.time()))
    while not stop.wait(0.5):
        t = time.perf_counter()
        res = client.call(Json.Request(request=json.dumps({"seed": 0})), timeout_sec=10)
        out.append(time.perf_counter() - t if res is not None and json.loads(res.response).get("ok") else math.inf)
    spin.close()
    node.destroy_node()
    rclpy.try_shutdown()


def pct(xs: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(xs) * 1000, q)) if xs else math.nan


def cmd_load(args: argparse.Namespace) -> int:
    system = System()
    # The one client's calls are a random sample of the N clients' requests, so that both imagine
    # the same mix of trajectory lengths (a request's seed decides when its trajectory ends).
    try:
        lat1, fail1, wall1, _, steps1 = run_clients(1, args.baseline_calls, args.calls)
        probe: list[float] = []
        stop = threading.Event()
        start_at = time.time() + 8.0
        prober = threading.Thread(target=probe_env, args=(stop, probe, start_at))
        prober.start()
        latn, failn, walln, batched, stepsn = run_clients(args.clients, args.calls, start_at=start_at)
        stop.set()
        prober.join()
    finally:
        code = system.stop()
    rate1, raten = len(lat1) / wall1, len(latn) / walln
    print(
        f"one client:  {len(lat1)} calls (a sample of the others' requests), {rate1:6.1f} calls/s, "
        f"{steps1 / wall1:6.1f} steps/s, {steps1 / len(lat1):.1f} steps per call, p50 {pct(lat1, 50):.0f} ms, "
        f"p99 {pct(lat1, 99):.0f} ms"
    )
    print(
        f"{args.clients} clients: {len(latn)} calls, {raten:6.1f} calls/s, {stepsn / walln:6.1f} steps/s, "
        f"{stepsn / len(latn):.1f} steps per call, p50 {pct(latn, 50):.0f} ms, p99 {pct(latn, 99):.0f} ms, "
        f"failures {failn + fail1}; requests sharing a step: mean of each call's most {np.mean(batched):.1f}, "
        f"max {max(batched)}"
    )
    print(
        f"/env/reset during the load: {len(probe)} calls, p50 {pct(probe, 50):.0f} ms, max {max(probe) * 1000:.0f} ms"
    )
    ratio = raten / rate1
    ok = ratio >= 5 and pct(latn, 99) < 1000 and failn + fail1 == 0 and all(math.isfinite(p) for p in probe)
    print(
        f"throughput ratio {ratio:.1f}x in calls/s, {(stepsn / walln) / (steps1 / wall1):.1f}x in steps/s "
        f"(target >= 5x), p99 {pct(latn, 99):.0f} ms (target < 1000 ms): {'met' if ok else 'NOT met'}; "
        f"launcher exit {code}"
    )
    return 0 if ok else 1


def load_on(decoding: str | None, clients: int, calls: int) -> dict:
    """The load of `clients` clients on a system started with LWM_DECODING=`decoding` (None: the
    default path): calls/s, p50/p99 (ms), failures and the launcher's exit code."""
    before = os.environ.pop("LWM_DECODING", None)
    if decoding is not None:
        os.environ["LWM_DECODING"] = decoding
    try:
        system = System()
        try:
            lat, fail, wall, _, _ = run_clients(clients, calls)
        finally:
            code = system.stop()
    finally:
        os.environ.pop("LWM_DECODING", None)
        if before is not None:
            os.environ["LWM_DECODING"] = before
    return {"rate": len(lat) / wall, "p50": pct(lat, 50), "p99": pct(lat, 99), "failures": fail, "exit": code}


PATHS_RATIO, PATHS_P99_MS = 2.0, 200.0  # issue 32's targets against the reference path


def cmd_paths(args: argparse.Namespace) -> int:
    ratios, p99s, met, failures = [], [], 0, 0
    for k in range(1, args.pairs + 1):
        ref = load_on("reference", args.clients, args.calls)
        now = load_on(None, args.clients, args.calls)
        ratio = now["rate"] / ref["rate"]
        ratios.append(ratio)
        p99s.append(now["p99"])
        failures += ref["failures"] + now["failures"]
        both = ratio >= PATHS_RATIO and now["p99"] < PATHS_P99_MS
        met += both
        print(
            f"pair {k}: reference {ref['rate']:.1f} calls/s (p50 {ref['p50']:.0f} ms, p99 {ref['p99']:.0f} ms), "
            f"default {now['rate']:.1f} calls/s (p50 {now['p50']:.0f} ms, p99 {now['p99']:.0f} ms): "
            f"{ratio:.2f}x, {'both targets met' if both else 'NOT both met'}; failures "
            f"{ref['failures'] + now['failures']}, launcher exits {ref['exit']} {now['exit']}",
            flush=True,
        )
    ratio, p99 = float(np.median(ratios)), float(np.median(p99s))
    ok = ratio >= PATHS_RATIO and p99 < PATHS_P99_MS and failures == 0
    print(
        f"{args.clients} clients, {args.pairs} pairs: median {ratio:.2f}x the reference's calls/s "
        f"(each {', '.join(f'{r:.2f}x' for r in ratios)}; target >= {PATHS_RATIO:g}x), median p99 {p99:.0f} ms "
        f"(target < {PATHS_P99_MS:g} ms); both targets in {met} of {args.pairs} pairs; failures {failures}: "
        f"{'met' if ok else 'NOT met'}"
    )
    return 0 if ok else 1


# ---------------------------------------------------------------------------------- malformed
TOPICS = {  # what each node reads, and the message kind it expects
    "/feedback/manual": "manual",
    "/env/manual": "manual",
    "/review/feedback": "review_feedback",
    "/review/labels": "labels",
    "/env/state": "state",
    "/lwm/status": "status",
}
SERVICES = ("/lwm/imagine", "/env/reset", "/env/step")


def malformed(i: int) -> str:
    """The i-th bad payload (cycling through the kinds)."""
    kinds = [
        lambda: "{not json",
        lambda: json.dumps({"version": 1, "descriptions": 42}),
        lambda: json.dumps({"version": 1, "descriptions": ["x" * (1 << 20), "y", "z"]}),  # 1 MB
        lambda: "[" * 10000 + "]" * 10000,
        lambda: '{"version": 1, "observation": NaN, "actions": [[NaN]]}',
        lambda: json.dumps({"version": 1, "observation": OBS, "actions": [[7, -1, 99]]}),
        lambda: json.dumps({"version": 1, "observation": OBS, "actions": [[3] * 10000]}),
        lambda: json.dumps({"version": 1, "descriptions": ["\u202e\u0000\ud7ff" * 3] * 3, "source": "\U0001f600"}),
        lambda: json.dumps({"version": 99}),
        lambda: json.dumps({"seed": "zero", "action": 1.5}),
        lambda: "",
        lambda: json.dumps([1, 2, 3]),
    ]
    return kinds[i % len(kinds)]()


def cmd_malformed(args: argparse.Namespace) -> int:
    import rclpy
    from lwm_interfaces.srv import Json
    from lwm_nodes.common import ERRORS_TOPIC, EVENTS, FEEDBACK, ros_environment
    from lwm_nodes.ros_cli import BackgroundSpin
    from rclpy.qos import QoSProfile
    from std_msgs.msg import String

    system = System()
    human = subprocess.Popen(  # the human node reads the planner's topics; stdin closed: no typing
        [sys.executable, "-m", "lwm_nodes.human_node"],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        cwd=ROOT,
    )
    topics = {**TOPICS, "/planner/plan": "plan", "/planner/label_request": "label_request", "/planner/report": "report"}
    try:
        ros_environment()
        rclpy.init()
        node = rclpy.create_node("stress_malformed")
        spin = BackgroundSpin(node)
        errors = []
        lock = threading.Lock()

        topic_reports = [0]  # counted as they come: the pacing below reads it after every payload

        def on_error(msg: String) -> None:
            error = json.loads(msg.data)
            with lock:
                errors.append(error)
                topic_reports[0] += error["where"] in topics

        node.create_subscription(String, ERRORS_TOPIC, on_error, QoSProfile(depth=1000, reliability=EVENTS.reliability))
        # Transient local, as the nodes' readers of these topics are (a volatile writer would not match).
        pubs = {t: node.create_publisher(String, t, FEEDBACK) for t in topics}
        clients = {s: node.create_client(Json, s) for s in SERVICES}
        for c in clients.values():
            c.wait_for_service(timeout_sec=60)
        time.sleep(3)  # discovery of every subscriber
        pids = {**system.node_pids(), "human": human.pid}
        before = {name: rss_mb(pid) for name, pid in pids.items()}
        targets = list(topics) + list(SERVICES)
        sent_topics, expected, answered, service_ok = 0, 0, 0, 0
        began = time.perf_counter()
        for i in range(args.payloads):
            target, text = targets[i % len(targets)], malformed(i // len(targets) + i)
            if target in clients:
                res = clients[target].call(Json.Request(request=text), timeout_sec=30)
                answered += res is not None
                service_ok += res is not None and json.loads(res.response).get("ok", False)
            else:
                pubs[target].publish(String(data=text))
                sent_topics += 1
                expected += pubs[target].get_subscription_count()  # each reading node reports it
                # Pace: the nodes read these topics as state (depth 1), where a newer message
                # supersedes an unread one; wait for this one's reports before the next.
                deadline = time.monotonic() + 5
                while time.monotonic() < deadline:
                    if topic_reports[0] >= expected:
                        break
                    time.sleep(0.002)
            if i % 1000 == 999:
                print(f"  {i + 1} sent; topic reports {topic_reports[0]} of {expected}", file=sys.stderr, flush=True)
        elapsed = time.perf_counter() - began
        time.sleep(3)
        after = {name: rss_mb(pid) for name, pid in pids.items()}
        alive = {name: Path(f"/proc/{pid}").exists() for name, pid in pids.items()}
        res = clients["/lwm/imagine"].call(Json.Request(request=json.dumps(imagine_request(0))), timeout_sec=30)
        still_serving = res is not None and json.loads(res.response).get("ok")
        spin.close()
        node.destroy_node()
        rclpy.try_shutdown()
    finally:
        human.send_signal(signal.SIGINT)
        human.wait(20)
        code = system.stop()
    by_where: dict[str, int] = {}
    for e in errors:
        by_where[e["where"]] = by_where.get(e["where"], 0) + 1
    reported_topics = sum(v for k, v in by_where.items() if k in topics)
    print(
        f"{args.payloads} malformed payloads in {elapsed:.0f} s: {sent_topics} on {len(topics)} topics, "
        f"{args.payloads - sent_topics} to {len(SERVICES)} services"
    )
    print(
        f"errors reported on {ERRORS_TOPIC}: {len(errors)}; for topic payloads {reported_topics} of {expected} "
        f"expected (one per reading node); by where: {by_where}"
    )
    print(f"service calls answered {answered}/{args.payloads - sent_topics}, answered ok {service_ok}")
    for name in pids:
        print(f"  {name:<10} RSS {before[name]:7.1f} MB -> {after[name]:7.1f} MB, alive {alive[name]}")
    ok = (
        all(alive.values())
        and still_serving
        and answered == args.payloads - sent_topics
        and service_ok == 0
        and reported_topics == expected
    )
    print(f"nodes alive and serving: {'yes' if ok else 'NO'}; launcher exit {code}")
    return 0 if ok else 1


# ---------------------------------------------------------------------------------- kill -9
def ledger_records(path: Path) -> list[tuple[str, str, dict]]:
    import sqlite3

    if not path.exists():
        return []
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=30)
    try:
        return [(r, k, json.loads(p)) for r, k, p in db.execute("SELECT review_id, kind, payload FROM records")]
    except sqlite3.OperationalError:  # the planner has not created the table yet
        return []
    finally:
        db.close()


def ledger_problems(path: Path) -> list[str]:
    """What would show a lost or doubled record in a finished review's ledger."""
    import sqlite3

    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    integrity = db.execute("PRAGMA integrity_check").fetchone()[0]
    db.close()
    problems = [] if integrity == "ok" else [f"integrity_check: {integrity}"]
    records = ledger_records(path)
    for review in sorted({r for r, _, _ in records}):
        mine = [(k, p) for r, k, p in records if r == review]
        plans = [p["plan_id"] for k, p in mine if k == "plan"]
        if plans != list(range(1, len(plans) + 1)):
            problems.append(f"{review}: plans recorded {plans}, not 1..{len(plans)} once each")
        decisions = [(p["plan_id"], p["decision"]) for k, p in mine if k == "feedback"]
        if len(decisions) != len(set(decisions)):
            problems.append(f"{review}: a decision recorded twice: {decisions}")
        if any(plan not in plans for plan, _ in decisions):
            problems.append(f"{review}: feedback on a plan that was never recorded: {decisions}")
        answered = [p["request_id"] for k, p in mine if k == "labels"]
        if len(answered) != len(set(answered)):
            problems.append(f"{review}: labels of a request recorded twice: {answered}")
        reports = sum(k == "report" for k, _ in mine)
        if reports != 1:
            problems.append(f"{review}: {reports} execution reports")
    return problems


def cmd_kill(args: argparse.Namespace) -> int:
    system = System(["--iterations", str(args.iterations)], human="--scripted", restarts=4)
    order = ["world_model", "planner", "env", "human"]
    log = []
    try:
        for name in order:
            # Kill once the review has moved since the last kill: a plan or a label request more.
            seen = len(ledger_records(system.ledger))
            deadline = time.monotonic() + 180
            while len(ledger_records(system.ledger)) <= seen and time.monotonic() < deadline:
                if system.proc.poll() is not None:
                    break
                time.sleep(0.5)
            pid = system.node_pids().get(name)
            if pid is None or system.proc.poll() is not None:
                log.append(f"{name}: not running (the review may have ended)")
                continue
            os.kill(pid, signal.SIGKILL)
            began = time.monotonic()
            while system.node_pids().get(name) in (None, pid) and time.monotonic() - began < 60:
                time.sleep(0.1)
            log.append(f"{name}: killed (pid {pid}), restarted after {time.monotonic() - began:.1f} s")
        code = system.proc.wait(900)
    except subprocess.TimeoutExpired:
        code = system.stop()
    summary = [line.strip() for line in system.lines if "SUMMARY" in line]
    problems = ledger_problems(system.ledger)
    for line in log:
        print(line)
    print(summary[-1] if summary else "no summary: the review did not finish")
    print(f"launcher exit {code}; ledger {system.ledger}: {'ok' if not problems else problems}")
    ok = bool(summary) and not problems and code == 0
    print(f"every node killed once, the review finished, nothing lost or doubled: {'yes' if ok else 'NO'}")
    return 0 if ok else 1


def cmd_shutdown(args: argparse.Namespace) -> int:
    import re

    system = System(human="--scripted", restarts=0)
    start_at = time.time() + 8.0
    clients = [
        subprocess.Popen(
            [sys.executable, "-c", CLIENT, "/lwm/imagine", "100000", str(start_at), str(Path(__file__).parent)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        for _ in range(args.clients)
    ]
    time.sleep(8.0 + args.load_seconds)  # the clients are calling; the planner is reviewing
    system.proc.send_signal(signal.SIGTERM)
    code = system.proc.wait(60)
    for c in clients:
        c.kill()
        c.wait()
    times = {
        m.group(1): float(m.group(2))
        for line in system.lines
        if (m := re.search(r"launcher: (\w+) exit code .*, ([\d.]+) s after SIGTERM", line))
    }
    for name, took in times.items():
        print(f"  {name:<10} exited {took:.2f} s after SIGTERM")
    ok = len(times) == 4 and max(times.values()) <= 2.0
    print(f"every node within 2 s of SIGTERM under load: {'yes' if ok else 'NO'}; launcher exit {code}")
    return 0 if ok else 1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="part", required=True)
    p = sub.add_parser("load", help="8 clients against one: calls/s, latency, batching")
    p.add_argument("--clients", type=int, default=8, help="concurrent client processes")
    p.add_argument("--calls", type=int, default=1000, help="calls per client")
    p.add_argument("--baseline-calls", type=int, default=200, help="calls of the lone client")
    p.set_defaults(func=cmd_load)
    p = sub.add_parser("paths", help="the load on the reference path and on the default, in alternating launches")
    p.add_argument("--pairs", type=positive_int, default=3, help="launches of each path, alternating")
    p.add_argument("--clients", type=int, default=8, help="concurrent client processes")
    p.add_argument("--calls", type=int, default=500, help="calls per client")
    p.set_defaults(func=cmd_paths)
    p = sub.add_parser("malformed", help="bad payloads on every topic and service the nodes read")
    p.add_argument("--payloads", type=int, default=10000, help="how many (spread over the targets)")
    p.set_defaults(func=cmd_malformed)
    p = sub.add_parser("kill", help="kill -9 each node in turn during a scripted review")
    p.add_argument("--iterations", type=int, default=6, help="online-imitation rounds of the review")
    p.set_defaults(func=cmd_kill)
    p = sub.add_parser("shutdown", help="SIGTERM under load: every node's exit time")
    p.add_argument("--clients", type=int, default=8, help="client processes calling /lwm/imagine")
    p.add_argument("--load-seconds", type=float, default=20.0, help="seconds of load before SIGTERM")
    p.set_defaults(func=cmd_shutdown)
    args = parser.parse_args()
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(main())
