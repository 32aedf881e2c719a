"""The live view for Foxglove against the real system (`--foxglove PORT --record FILE`): a
WebSocket client speaking Foxglove's protocol (written here from the protocol's description, not
Foxglove's code) is offered the board and plan images, subscribes to the board and receives the
real board after a step; after the run, the view's MCAP file opens with the `mcap` package's
reader (independent of the writer) and holds the boards, the plans and the plans' summaries."""

from __future__ import annotations

import base64
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import time

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("foxglove")
from lwm_nodes import domains  # noqa: E402
from mcap.reader import make_reader  # noqa: E402

pytestmark = pytest.mark.system


class FoxgloveClient:
    """Just enough of a WebSocket client (RFC 6455) for Foxglove's JSON and binary messages. It offers
    both subprotocol names: the SDK's server (0.30) speaks `foxglove.sdk.v1`, earlier ones
    `foxglove.websocket.v1`."""

    def __init__(self, host: str, port: int) -> None:
        self.sock = socket.create_connection((host, port), timeout=30)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            (
                f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                "Sec-WebSocket-Protocol: foxglove.sdk.v1, foxglove.websocket.v1\r\n\r\n"
            ).encode()
        )
        head = b""
        while b"\r\n\r\n" not in head:
            head += self.sock.recv(1)
        assert head.startswith(b"HTTP/1.1 101"), head

    def _exact(self, n: int) -> bytes:
        out = b""
        while len(out) < n:
            chunk = self.sock.recv(n - len(out))
            assert chunk, "the server closed the connection"
            out += chunk
        return out

    def receive(self) -> tuple[int, bytes]:
        """(opcode, payload) of the next frame: 1 text, 2 binary."""
        b0, b1 = self._exact(2)
        n = b1 & 0x7F
        if n == 126:
            (n,) = struct.unpack(">H", self._exact(2))
        elif n == 127:
            (n,) = struct.unpack(">Q", self._exact(8))
        return b0 & 0x0F, self._exact(n)

    def send(self, payload: dict) -> None:
        data, mask = json.dumps(payload).encode(), os.urandom(4)
        size = bytes([0x80 | len(data)]) if len(data) < 126 else bytes([0x80 | 126]) + struct.pack(">H", len(data))
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(data))
        self.sock.sendall(bytes([0x81]) + size + mask + masked)


def test_the_live_view_serves_the_boards_to_foxglove_and_writes_them_beside_the_recording(tmp_path):
    env = {
        **os.environ,
        "ROS_DOMAIN_ID": str(domains.claim()),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "ROS_LOG_DIR": str(tmp_path / "roslog"),
    }
    record = tmp_path / "review.mcap"
    cmd = [sys.executable, "-m", "lwm_nodes.launcher", "--no-human", "--quiet", "--foxglove", "0", "--record"]
    cmd += [str(record), "--iterations", "1", "--futures", "2", "--log-dir", str(tmp_path / "logs")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    address = None
    try:
        for line in proc.stdout:
            if "FOXGLOVE live view at" in line:
                address = line.split(" at ")[-1].strip()
            if "nodes ready" in line or proc.poll() is not None:
                break
        assert address and address.startswith("ws://127.0.0.1:"), "the launcher printed no live view address"
        client = FoxgloveClient("127.0.0.1", int(address.rsplit(":", 1)[1]))
        channels: dict[str, dict] = {}
        deadline = time.monotonic() + 60
        while not {"/board", "/plan"} <= set(channels) and time.monotonic() < deadline:
            opcode, data = client.receive()
            if opcode == 1 and (msg := json.loads(data)).get("op") == "advertise":
                channels.update({c["topic"]: c for c in msg["channels"]})
        assert channels["/board"]["schemaName"] == channels["/plan"]["schemaName"] == "foxglove.RawImage"
        client.send({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channels["/board"]["id"]}]})
        time.sleep(1.0)  # the subscription reaches the server before the board changes
        step = [sys.executable, "-m", "lwm_models.cli.main", "ros", "call", "/env/step", '{"action": 4}']
        assert subprocess.run(step, env=env, capture_output=True, text=True, timeout=60).returncode == 0
        while True:  # a message frame: opcode byte 1, subscription id, log time, then the message
            opcode, data = client.receive()
            if opcode == 2 and data[0] == 1:
                assert struct.unpack("<I", data[1:5])[0] == 7
                assert len(data) > 240 * 240 * 3  # a 10 x 10 board of 24-pixel cells, rgb8
                break
        # The planner's first plan, then stop: the view's MCAP is closed on the way out.
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and "plan 1" not in (tmp_path / "logs" / "planner.log").read_text():
            time.sleep(0.5)
    finally:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, out[-3000:]
    view = record.with_suffix(".view.mcap")
    with open(view, "rb") as f:
        got = [
            (channel.topic, schema.name, message.data) for schema, channel, message in make_reader(f).iter_messages()
        ]
    topics = {topic: name for topic, name, _ in got}
    assert topics["/board"] == topics["/plan"] == "foxglove.RawImage", topics
    boards = [data for topic, _, data in got if topic == "/board"]
    assert len(boards) >= 2  # the start, and the board after the step
    summaries = [json.loads(data) for topic, _, data in got if topic == "/plan_summary"]
    assert summaries and summaries[0]["review_id"] == "newall-test:0:0" and 0 <= summaries[0]["death_share"] <= 1
