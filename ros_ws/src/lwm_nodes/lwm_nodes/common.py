"""What every node shares: QoS profiles, JSON topics with validation and error reports, and a
spin loop that shuts down cleanly on SIGINT/SIGTERM."""

from __future__ import annotations

import ctypes
import faulthandler
import os
import signal
import sys
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path

import rclpy
from rclpy.executors import Executor, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import String

from lwm_models import messages, signing

# Manuals and statuses are state, not events: a node that starts late must still get the latest.
LATCHED = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
EVENTS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=50,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
# Review feedback is kept (transient local) so that a planner restarted mid-review receives what
# it missed; it skips what its ledger already holds.
FEEDBACK = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=50,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
# Answers to what a sender gave a node (feedback, labels, a manual): kept (transient local), so
# that a sender whose subscription matched a moment late still finds its answer.
ACKS = FEEDBACK
# Absolute, like /rosout: one channel for the whole system, a fleet's namespaced agents included,
# so that a sender hears the answer of whichever node took its message (acks carry its msg_id).
ERRORS_TOPIC = "/lwm/errors"
ACKS_TOPIC = "/lwm/acks"
FASTDDS_PROFILE = Path(__file__).resolve().parents[3] / "fastdds_profile.xml"


def ros_environment() -> None:
    """Defaults every process of the system shares, set before rclpy starts: discovery on this
    machine only unless the user says otherwise, and the fast-discovery Fast DDS profile."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if FASTDDS_PROFILE.is_file():
        os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(FASTDDS_PROFILE))


DIAGNOSTICS_TOPIC = "/diagnostics"  # ROS's own convention: absolute, one for the whole system
RECENT_ERROR_S = 30.0  # a node reports WARN for this long after an error it reported


class JsonNode(Node):
    """A node that speaks validated JSON on std_msgs/String, reports bad input on /lwm/errors and
    its health on /diagnostics (diagnostic_msgs/DiagnosticArray, every `diagnostics_period` s)."""

    def __init__(self, name: str) -> None:
        super().__init__(name)
        # On /diagnostics as "started": a value that changes tells the others the node came back.
        self.started = round(time.time(), 3)
        self._errors = self.create_publisher(String, ERRORS_TOPIC, EVENTS)
        self._acks = None  # created by the first subscription that answers its senders
        self.error_count = 0
        self._last_error: tuple[float, str] | None = None  # (monotonic time, what)
        # Service requests and responses published as events (<service>/_service_event), so that a
        # recording holds them: "contents" (the launcher's choice with --record) or "off".
        self.introspection = self.declare_parameter("service_introspection", "off").value
        if self.introspection not in ("off", "contents"):
            raise ValueError(f"service_introspection must be 'off' or 'contents', not {self.introspection!r}")
        period = float(self.declare_parameter("diagnostics_period", 1.0).value)
        if period > 0:
            from diagnostic_msgs.msg import DiagnosticArray

            self._diagnostics = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, EVENTS)
            self.create_timer(period, self.publish_diagnostics)

    def json_service(self, name: str, callback, **kwargs):
        """A lwm_interfaces/Json service; with `service_introspection` "contents", each request and
        response is also published on <name>/_service_event (lwm_interfaces/srv/Json_Event)."""
        from lwm_interfaces.srv import Json

        service = self.create_service(Json, name, callback, **kwargs)
        if self.introspection == "contents":
            from rclpy.service_introspection import ServiceIntrospectionState

            service.configure_introspection(self.get_clock(), EVENTS, ServiceIntrospectionState.CONTENTS)
        return service

    def health(self) -> tuple[str, dict[str, object]]:
        """What the node says of itself on /diagnostics: a one-line message and named values.
        Nodes add their own (queue lengths, batch sizes, the review's phase)."""
        return "serving", {}

    def publish_diagnostics(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        try:
            message, values = self.health()
            level = DiagnosticStatus.OK
        except Exception as exc:  # the report must not take the node down either
            message, values, level = f"health unknown: {exc}", {}, DiagnosticStatus.ERROR
        values = {**values, "errors reported": self.error_count, "started": self.started}
        if self._last_error is not None and time.monotonic() - self._last_error[0] < RECENT_ERROR_S:
            level = max(level, DiagnosticStatus.WARN)
            message = f"{message}; last error: {self._last_error[1]}"
        status = DiagnosticStatus(
            level=level,
            name=self.get_fully_qualified_name(),
            message=message[:500],
            hardware_id=os.uname().nodename,
            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()],
        )
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(array)

    def close(self) -> None:
        """Called on SIGINT/SIGTERM before the executor shuts down: a node whose callbacks may be
        waiting (for a batch, a worker) releases them here, so that it exits within 2 s."""

    def declare_threads(self) -> int:
        """Parameter `threads` (default 1): torch's intra-op threads. The system's nodes share a
        few cores; torch's default (one thread per core) made every /lwm/imagine step about 20x
        slower while another process used the other core (measured: ~1 s instead of ~40 ms)."""
        import torch

        threads = int(self.declare_parameter("threads", 1).value)
        torch.set_num_threads(max(1, threads))
        return threads

    def json_publisher(self, topic: str, kind: str, qos: QoSProfile) -> Callable[[dict], None]:
        pub = self.create_publisher(String, topic, qos)

        def publish(payload: dict) -> None:
            pub.publish(String(data=messages.dump(kind, payload)))

        return publish

    def json_subscription(
        self, topic: str, kind: str, handler: Callable[[dict], str | None], qos: QoSProfile, acks: bool = False
    ):
        """Subscribe with validation: a payload that does not parse, or that the handler refuses
        (raises), is reported on /lwm/errors and changes nothing. With `acks`, every message also
        gets an answer on /lwm/acks for its sender: taken (with what the handler returned, a line
        saying what it did) or refused, with the reason in plain words."""
        if acks and self._acks is None:
            self._acks = self.create_publisher(String, ACKS_TOPIC, ACKS)
        where = self.resolve_topic_name(topic)  # errors and answers name the topic in full: one of a fleet's

        def callback(msg: String) -> None:
            msg_id = None
            try:
                msg_id = messages.msg_id_of(msg.data)
                payload = messages.parse(kind, msg.data)
                done = handler(payload)
            except signing.ReplayedSignature as exc:
                # A node restarted is sent again what it took before its crash (transient-local
                # topics): refused, since it was taken once, but nobody did anything wrong.
                self.get_logger().info(f"{where}: {exc}")
                if acks:
                    self.acknowledge(where, msg_id, False, messages.plain_reason(exc), msg.data)
                return
            except Exception as exc:  # a bad message must never take the node down
                self.report_error(where, exc, msg.data)
                if acks:
                    self.acknowledge(where, msg_id, False, messages.plain_reason(exc), msg.data)
                return
            if acks:
                self.acknowledge(where, msg_id, True, done or "taken", msg.data)

        return self.create_subscription(String, topic, callback, qos)

    def acknowledge(self, topic: str, msg_id: str | None, ok: bool, reason: str, payload: str = "") -> None:
        ack = {"node": self.get_name(), "topic": topic, "msg_id": msg_id, "ok": ok, "reason": reason[:2000]}
        if not ok or msg_id is None:
            ack["payload_excerpt"] = payload[:500]
        self._acks.publish(String(data=messages.dump("ack", ack)))

    def report_error(self, where: str, exc: Exception, payload: str = "") -> None:
        text = f"{type(exc).__name__}: {exc}" if not isinstance(exc, messages.MessageError) else str(exc)
        self.get_logger().error(f"{where}: {text}")
        self.error_count += 1
        self._last_error = (time.monotonic(), f"{where}: {text}"[:200])
        self._errors.publish(
            String(
                data=messages.dump(
                    "error",
                    {"node": self.get_name(), "where": where, "error": text[:2000], "payload_excerpt": payload[:500]},
                )
            )
        )


ANSWER_WINDOW_S = 30.0  # an answer not come in this long is taken as never coming (a node restarted)


class Answers:
    """What a node sent, by msg_id, until the receiving node answers it on /lwm/acks: a sender
    (the human node, the fleet page) waits for the answer to show the person, in words, whether
    what they sent was taken. `on_answer(ack, payload)` hears each first answer to its messages;
    answers to others, and repeats, are ignored."""

    def __init__(self, node: JsonNode, on_answer: Callable[[dict, dict], None] | None = None) -> None:
        self.node = node
        self.on_answer = on_answer
        self._sent: dict[str, dict] = {}
        self._lock = threading.Lock()
        node.create_subscription(String, ACKS_TOPIC, self._on_ack, ACKS)

    def sender(self, publish: Callable[[dict], None]) -> Callable[[dict], str]:
        """`publish`, with a fresh msg_id on each payload; the returned function gives the msg_id."""

        def send(payload: dict) -> str:
            msg_id = f"{self.node.get_name()}-{uuid.uuid4().hex[:12]}"
            with self._lock:
                self._sent[msg_id] = {
                    "event": threading.Event(), "ack": None, "payload": payload, "at": time.monotonic()
                }  # fmt: skip
            publish({**payload, "msg_id": msg_id})
            return msg_id

        return send

    def _on_ack(self, msg: String) -> None:
        try:
            ack = messages.parse("ack", msg.data)
        except messages.MessageError as exc:
            self.node.report_error(ACKS_TOPIC, exc, msg.data)
            return
        with self._lock:
            entry = self._sent.get(ack["msg_id"] or "")
            if entry is None or entry["ack"] is not None:
                return
            entry["ack"] = ack
        entry["event"].set()
        if self.on_answer is not None:
            self.on_answer(ack, entry["payload"])

    def wait(self, msg_id: str, timeout: float) -> dict | None:
        """The answer to msg_id, waiting up to `timeout` seconds; None if none came."""
        with self._lock:
            entry = self._sent.get(msg_id)
        if entry is None or not entry["event"].wait(timeout):
            return None
        return entry["ack"]

    def awaited(self, within: float = ANSWER_WINDOW_S) -> tuple[int, int]:
        """Messages sent that no node has answered yet: (sent in the last `within` seconds, whose
        answer may still come; sent before, whose answer never came)."""
        now = time.monotonic()
        with self._lock:
            open_ = [entry["at"] for entry in self._sent.values() if entry["ack"] is None]
        recent = sum(now - at <= within for at in open_)
        return recent, len(open_) - recent


def agent_topic(agent: str, name: str) -> str:
    """A fleet agent's topic or service, relative to the node's namespace ("" names the node's own)."""
    return f"{agent}/{name}" if agent else name


def declare_agents(node: Node) -> list[str]:
    """Parameter `agents`: the agents a node serves, their namespaces without slashes; [""] (the
    default) is the single agent in the node's own namespace."""
    return [a.strip("/") for a in node.declare_parameter("agents", [""]).value] or [""]


def make_executor(threads: int = 1) -> Executor:
    """The executor every process of the system spins: rclpy's EventsExecutor (C++, event driven)
    unless LWM_EXECUTOR=single asks for the pure-Python SingleThreadedExecutor. The events one cut
    the /lwm/imagine service overhead by about a third (benchmarks/ros_latency.py). With `threads`
    > 1, a MultiThreadedExecutor of that many threads."""
    if threads > 1:
        return MultiThreadedExecutor(num_threads=threads)
    choice = os.environ.get("LWM_EXECUTOR", "events")
    if choice == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    if choice == "single":
        return SingleThreadedExecutor()
    raise ValueError(f"LWM_EXECUTOR must be 'events' or 'single', not {choice!r}")


def run(make_node: Callable[[], Node], stop: threading.Event | None = None, threads: int = 1) -> int:
    """Create the node, print READY, spin until SIGINT/SIGTERM, shut down in order, and end the
    process: within 2 s of the signal, under load (benchmarks/ros_stress.py shutdown).
    `threads` > 1 spins a MultiThreadedExecutor, for a node whose callbacks may wait on each other
    (the world-model server's service calls wait for their batch).

    rclpy's own signal handlers are off: they race with an early signal; an Event set by our
    handlers ends the spin loop instead (why: docs/ros.md, "Shutting down").
    Work still running in the node's own threads (learning, imagination calls) is abandoned, not
    waited for: the process ends with os._exit. Nothing acknowledged is lost that way: the ledger
    commits every record as it happens, and a restarted node resumes the review from it (the same
    as after a kill -9, which the tests do).
    """
    stop = stop or threading.Event()
    ros_environment()
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    node = None
    executor = make_executor(threads)
    code = 0
    try:
        node = make_node()
        executor.add_node(node)
        print(f"READY {node.get_name()}", flush=True)
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.1)
    except Exception as exc:
        print(f"fatal: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
        code = 1
    finally:
        marks = [("", time.monotonic())]
        print("stopping", flush=True)
        _exit_by_deadline(code, marks)
        if isinstance(node, JsonNode):
            node.close()  # before the executor waits for running callbacks: let them end now
        marks.append(("close", time.monotonic()))
        executor.shutdown(timeout_sec=1.0)
        marks.append(("executor", time.monotonic()))
        if node is not None:
            node.destroy_node()
        marks.append(("node", time.monotonic()))
        rclpy.try_shutdown()
        marks.append(("rclpy", time.monotonic()))
        phases = ", ".join(f"{name} {t - marks[i][1]:.2f}" for i, (name, t) in enumerate(marks[1:]))
        print(f"stopped in {marks[-1][1] - marks[0][1]:.2f} s ({phases})", flush=True)
        sys.stderr.flush()
    os._exit(code)


STOP_DEADLINE_S = 1.5  # teardown may take this long; the process ends by 2 s after the signal


def _exit_by_deadline(code: int, marks: list[tuple[str, float]]) -> None:
    """End the process STOP_DEADLINE_S after teardown began, however far it got, with the run's
    exit code. Teardown inside rclpy/Fast DDS stalled now and then (a node not gone 10 s after
    SIGTERM, issue 12; once, in CI, rclpy's destroy_node holding the GIL), and nothing left to do
    there matters once the ledger has committed. Three guards: a Python timer for a stall that
    releases the GIL, which names the phase that stalled; for one that holds it, faulthandler's
    C thread prints every thread's stack to the log (so the next stall says where it was), and a
    C timer then calls _exit with the run's code, which needs no Python to run. Where that timer
    cannot be armed (not glibc), faulthandler ends the process itself, with exit code 1."""

    def expire() -> None:
        done = marks[-1][0] or "start"
        print(f"stop deadline: teardown stalled after '{done}'; exiting anyway", flush=True)
        os._exit(code)

    timer = threading.Timer(STOP_DEADLINE_S, expire)
    timer.daemon = True
    timer.start()
    armed = exit_timer(STOP_DEADLINE_S + 0.4, code)
    faulthandler.dump_traceback_later(STOP_DEADLINE_S + 0.3, exit=not armed)


class _SigEvent(ctypes.Structure):
    """glibc's struct sigevent (64 bytes) as SIGEV_THREAD uses it: the value passed to the
    function, the signal number, the notification kind, the function and its thread attributes."""

    _fields_ = [
        ("value", ctypes.c_void_p),
        ("signo", ctypes.c_int),
        ("notify", ctypes.c_int),
        ("function", ctypes.c_void_p),
        ("attributes", ctypes.c_void_p),
        ("_pad", ctypes.c_byte * 32),
    ]


class _ITimerSpec(ctypes.Structure):
    _fields_ = [("interval", ctypes.c_long * 2), ("value", ctypes.c_long * 2)]


def exit_timer(seconds: float, code: int) -> bool:
    """Arm a POSIX timer that calls libc's _exit(code) from a thread of its own after `seconds`,
    without the GIL: glibc runs a SIGEV_THREAD timer's function in a new C thread and passes it
    the sigevent's value, which on the 64-bit ABIs lands where _exit reads its int. Returns False
    (nothing armed) where that cannot be done."""
    if not sys.platform.startswith("linux") or ctypes.sizeof(ctypes.c_void_p) != 8:
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        create, settime, exit_now = libc.timer_create, libc.timer_settime, libc._exit
    except (OSError, AttributeError):
        return False
    sigev_thread = 2
    event = _SigEvent(value=code & 0xFF, notify=sigev_thread, function=ctypes.cast(exit_now, ctypes.c_void_p).value)
    timer_id = ctypes.c_void_p()
    if create(time.CLOCK_MONOTONIC, ctypes.byref(event), ctypes.byref(timer_id)) != 0:
        return False
    whole = int(seconds)
    spec = _ITimerSpec(value=(ctypes.c_long * 2)(whole, int((seconds - whole) * 1e9)))
    return settime(timer_id, 0, ctypes.byref(spec), None) == 0


def json_caller(node: Node, client, kind: str | None, timeout: float) -> Callable[[dict], dict]:
    """A blocking JSON call of a service, for a worker thread while the executor spins elsewhere.
    Raises Unavailable when the service is not there or does not answer in `timeout` seconds (the
    caller may retry), MessageError when the answer is malformed."""
    import json

    from lwm_models.agent.imaginer import Unavailable

    def call(payload: dict) -> dict:
        if not client.wait_for_service(timeout_sec=timeout):
            raise Unavailable(f"{client.srv_name} is not available")
        request = client.srv_type.Request(request=json.dumps(payload))
        response = client.call(request, timeout_sec=timeout)
        if response is None:
            raise Unavailable(f"{client.srv_name} did not answer in {timeout:.0f} s")
        if kind is None:
            return json.loads(response.response)
        return messages.parse(kind, response.response)

    return call
