"""ROS overhead, in one run: the /lwm/imagine round trip against the same imagine call made
in-process, and a std_msgs/String topic round trip, across real processes on localhost.
Target: service overhead (round trip minus in-process time) <= 2 ms at the median. The two are
measured interleaved, call by call; LWM_EXECUTOR=single|events picks the rclpy executor of the
node and of this client (default: events).

    .venv/bin/python benchmarks/ros_latency.py [--checkpoint DIR] [--calls 200]

The world-model server node runs in its own process; this script is the client. The imagine request is
a one-step, one-trajectory imagination, so the ROS share of the time is what dominates.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import torch

if "ROS_DOMAIN_ID" not in os.environ:  # one no other run on this machine holds
    from lwm_nodes import domains

    os.environ["ROS_DOMAIN_ID"] = str(domains.claim())
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import rclpy  # noqa: E402
from lwm_interfaces.srv import Json  # noqa: E402
from lwm_nodes.common import EVENTS, ros_environment  # noqa: E402
from lwm_nodes.ros_cli import BackgroundSpin  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from lwm_models import messages  # noqa: E402
from lwm_models.world.model_server import WorldModelServer  # noqa: E402

MANUAL = [
    "the plane is the deadly enemy and it chases you.",
    "the ball has the secret message and runs away from you.",
    "the robot is the goal and never moves.",
]
REQUEST = {
    "version": 1,
    "observation": [[2, 2, 7], [10, 7, 2], [11, 7, 7], [15, 2, 2]],
    "manual": MANUAL,
    "actions": [[4]],
    "max_steps": 1,
    "seed": 0,
}
ECHO = r"""
import rclpy, sys
from std_msgs.msg import String
from lwm_nodes.common import EVENTS, ros_environment
ros_environment(); rclpy.init()
node = rclpy.create_node("echo_back")
pub = node.create_publisher(String, "/bench/pong", EVENTS)
node.create_subscription(String, "/bench/ping", lambda m: pub.publish(m), EVENTS)
print("READY", flush=True)
try:
    rclpy.spin(node)
except BaseException:  # SIGINT ends the benchmark
    pass
"""


def percentiles(xs: list[float]) -> str:
    a = np.array(xs) * 1000
    return f"p50 {np.percentile(a, 50):7.2f} ms  p99 {np.percentile(a, 99):7.2f} ms"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", default=None, help="world model (default: shipped EMMA-LWM)")
    parser.add_argument("--calls", type=int, default=200)
    args = parser.parse_args()
    ros_environment()
    sim_cmd = [sys.executable, "-m", "lwm_nodes.world_model_node"]
    if args.checkpoint:
        sim_cmd += ["--ros-args", "-p", f"checkpoint:={args.checkpoint}", "-p", "follow_env_manual:=false"]
    procs = [
        subprocess.Popen(sim_cmd, stdout=subprocess.PIPE, text=True),
        subprocess.Popen([sys.executable, "-c", ECHO], stdout=subprocess.PIPE, text=True),
    ]
    for p in procs:
        for line in p.stdout:
            if line.startswith("READY"):
                break
    try:
        # In-process: the same WorldModelServer the node wraps, the same validated JSON in and out.
        sim = WorldModelServer(args.checkpoint)
        text = json.dumps(REQUEST)

        rclpy.init()
        node = rclpy.create_node("bench_client")
        spinner = BackgroundSpin(node)
        client = node.create_client(Json, "/lwm/imagine")
        assert client.wait_for_service(timeout_sec=30), "world-model server not available"
        # Interleaved, so that both see the same machine: the overhead is the median of the
        # paired differences (round trip minus the in-process call just before it).
        local, remote = [], []
        for i in range(args.calls + 10):
            t = time.perf_counter()
            messages.dump("imagine_response", sim.imagine(messages.parse("imagine_request", text)))
            t_local = time.perf_counter() - t
            t = time.perf_counter()
            response = client.call(Json.Request(request=text), timeout_sec=30)
            t_remote = time.perf_counter() - t
            assert json.loads(response.response)["ok"]
            if i >= 10:  # warm-up
                local.append(t_local)
                remote.append(t_remote)

        got = threading.Event()
        node.create_subscription(String, "/bench/pong", lambda m: got.set(), EVENTS)
        pub = node.create_publisher(String, "/bench/ping", EVENTS)
        deadline = time.monotonic() + 10
        while (
            pub.get_subscription_count() == 0 or node.count_publishers("/bench/pong") == 0
        ) and time.monotonic() < deadline:
            time.sleep(0.05)
        payload = String(data=json.dumps({"x": "y" * 1000}))
        topic = []
        for _ in range(args.calls + 10):
            got.clear()
            t = time.perf_counter()
            pub.publish(payload)
            got.wait(5)
            topic.append(time.perf_counter() - t)
        topic = topic[10:]
        spinner.close()
        node.destroy_node()
        rclpy.try_shutdown()
    finally:
        for p in procs:
            p.send_signal(signal.SIGINT)
            p.wait(10)

    overhead = float(np.median(np.subtract(remote, local))) * 1000
    executor = os.environ.get("LWM_EXECUTOR", "events")
    print(f"executor: {executor}, {args.calls} calls, torch threads {torch.get_num_threads()}")
    print(f"imagine in-process      : {percentiles(local)}")
    print(f"/lwm/imagine round trip : {percentiles(remote)}")
    print(f"topic round trip (1 KB) : {percentiles(topic)}")
    print(f"service overhead at p50 : {overhead:.2f} ms (target <= 2 ms: {'met' if overhead <= 2 else 'MISSED'})")


if __name__ == "__main__":
    main()
