"""`lwm ros ...`: what ROS users do with the `ros2` command, which PyPI's ROS 2 does not ship.

    lwm ros nodes | topics | services
    lwm ros pub TOPIC JSON|@FILE [--kind manual] [--sign REVIEWER [--keys-file FILE]] [--volatile] [--wait 1.0] [-w N]
                                 [--ack-timeout 10]   (exit 1 when the receiving node refuses it)
    lwm ros echo TOPIC [--count N] [--timeout S] [--latched]
    lwm ros call SERVICE JSON|@FILE [--timeout S]   (exit 1 when the answer says "ok": false)
    lwm ros keys [--keys-file FILE] [--reviewer ID ...]
    lwm ros record FILE [--duration S]
    lwm ros play FILE [--rate R] [--topics T ...] [--wait S]
    lwm ros diagnostics [--seconds S] [--json]   (each node's health, from /diagnostics)

Discovery stays on this machine unless ROS_AUTOMATIC_DISCOVERY_RANGE says otherwise.

`lwm` finds this command through the entry point `ros = lwm_nodes.ros_cli:register` (group
lwm_models.commands, see setup.py). `lwm` loads that entry point on every run, whatever the command,
so this module imports rclpy and the message types only when a ROS command runs.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time
import uuid
from pathlib import Path
from typing import TYPE_CHECKING

from lwm_models.signing import DEFAULT_KEY_FILE as DEFAULT_KEYS  # stdlib only: cheap on every `lwm` run

if TYPE_CHECKING:
    from rclpy.node import Node


def _payload(arg: str, raw: bool = False) -> str:
    text = Path(arg[1:]).read_text() if arg.startswith("@") else arg
    if not raw:
        json.loads(text)  # a clear error before anything is sent
    return text


class BackgroundSpin:
    """Spin one executor in a thread (rclpy's spin_until_future_complete busy-loops), stopping
    it before the node is destroyed: destroying a node under a spinning thread aborts."""

    def __init__(self, node: Node) -> None:
        from lwm_nodes.common import make_executor

        self.executor = make_executor()
        self.executor.add_node(node)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        while not self.stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.executor.shutdown()


def cmd_graph(node: Node, what: str, settle: float) -> int:
    time.sleep(settle)  # let discovery find the others
    if what == "nodes":
        rows = sorted(f"{ns.rstrip('/')}/{name}" for name, ns in node.get_node_names_and_namespaces())
        rows = [r for r in rows if not r.endswith(node.get_name())]
    elif what == "topics":
        rows = [f"{name} [{', '.join(types)}]" for name, types in sorted(node.get_topic_names_and_types())]
    else:  # not this tool's own node's services
        own = f"/{node.get_name()}/"
        services = sorted(node.get_service_names_and_types())
        rows = [f"{name} [{', '.join(types)}]" for name, types in services if not name.startswith(own)]
    print("\n".join(rows))
    return 0


# Topics whose receiving node answers every message on /lwm/acks (taken, or refused and why).
# Matched on the name's end: an agent of a fleet has them in its namespace (/agent2/review/labels).
ACKED_TOPICS = {
    "review/feedback": "the planner",
    "review/labels": "the planner",
    "feedback/manual": "the world-model server",
}


def answered_by(topic: str) -> str | None:
    """Which node answers a message on this fully qualified topic, if any."""
    return next((who for end, who in ACKED_TOPICS.items() if topic == f"/{end}" or topic.endswith(f"/{end}")), None)


DISCOVERY_S = 3.0  # how long `call` looks for the service before it says nobody serves it
NO_ANSWER = 3  # exit status when no node answered in time (1: refused, 2: bad usage or input)


def cmd_pub(node: Node, args) -> int:
    """Publish one message. On a topic whose node answers (ACKED_TOPICS), wait for that answer:
    exit 0 when the message was taken, 1 when it was refused (the reason on stderr), NO_ANSWER
    when nobody answered within --ack-timeout."""
    from rclpy.duration import Duration
    from std_msgs.msg import String

    from lwm_models import messages
    from lwm_nodes.common import ACKS, ACKS_TOPIC, EVENTS, LATCHED

    text = _payload(args.payload, args.raw)
    args.topic = node.resolve_topic_name(args.topic)
    answerer = answered_by(args.topic) if args.ack_timeout > 0 else None
    msg_id = None
    if answerer and not args.raw:
        payload = json.loads(text)
        if isinstance(payload, dict):
            msg_id = payload.setdefault("msg_id", f"cli-{uuid.uuid4().hex[:12]}")
            text = json.dumps(payload)
    if args.sign:
        text = _signed(args, text)
    if args.kind and not (args.raw and args.sign):
        messages.parse(args.kind, text)
    answers: list[dict] = []
    got = threading.Event()
    if answerer:

        def on_ack(msg: String) -> None:
            ack = json.loads(msg.data)
            ours = ack.get("msg_id") == msg_id if msg_id else ack.get("payload_excerpt") == text[:500]
            if ours and ack.get("topic") == args.topic:
                answers.append(ack)
                got.set()

        # Before publishing: the answer may come at once. Transient local: a late match still sees it.
        node.create_subscription(String, ACKS_TOPIC, on_ack, ACKS)
    # A transient-local writer matches both volatile and transient-local readers (a volatile one
    # would not reach the system's latched subscriptions such as /feedback/manual).
    pub = node.create_publisher(String, args.topic, EVENTS if args.volatile else LATCHED)
    deadline = time.monotonic() + args.wait
    while pub.get_subscription_count() < args.wait_matching_subscriptions and time.monotonic() < deadline:
        time.sleep(0.02)
    if answerer and pub.get_subscription_count() == 0:
        # Nobody to take it: say so now rather than after waiting for an answer that cannot come.
        print(f"lwm ros: nothing subscribes to {args.topic} ({answerer} is not running?): not sent", file=sys.stderr)
        return NO_ANSWER
    pub.publish(String(data=text))
    # Reliable delivery needs the publisher alive until every reader has acknowledged the sample.
    pub.wait_for_all_acked(Duration(seconds=max(args.wait, 0.5)))
    print(f"published to {args.topic} ({pub.get_subscription_count()} subscriber(s))")
    if not answerer:
        return 0
    if not got.wait(args.ack_timeout):
        print(
            f"lwm ros: no answer from {answerer} in {args.ack_timeout:.0f} s: it may not be running, or it is "
            f"busy (the message may still be taken; see /lwm/acks)",
            file=sys.stderr,
        )
        return NO_ANSWER
    ack = answers[0]
    if ack["ok"]:
        print(f"taken by {ack['node']}: {ack['reason']}")
        return 0
    print(f"lwm ros: refused by {ack['node']}: {ack['reason']}", file=sys.stderr)
    return 1


LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}


def cmd_diagnostics(node: Node, args) -> int:
    """Listen to /diagnostics for --seconds and print each node's latest status; exit 1 when a
    node reports an error, 3 when none reported."""
    from diagnostic_msgs.msg import DiagnosticArray

    from lwm_nodes.common import DIAGNOSTICS_TOPIC, EVENTS

    latest: dict[str, dict] = {}

    def on_array(msg: DiagnosticArray) -> None:
        for st in msg.status:
            level = int.from_bytes(st.level, "little") if isinstance(st.level, bytes) else int(st.level)
            values = {kv.key: kv.value for kv in st.values}
            latest[st.name] = {"node": st.name, "level": LEVELS.get(level, str(level)), "message": st.message, **values}

    node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, on_array, EVENTS)
    time.sleep(args.seconds)
    found = [latest[name] for name in sorted(latest)]
    if not found:
        print(f"lwm ros: no node reported on {DIAGNOSTICS_TOPIC} in {args.seconds:.0f} s", file=sys.stderr)
        return NO_ANSWER
    for status in found:
        if args.json:
            print(json.dumps(status))
            continue
        print(f"{status['level']:5} {status['node']}: {status['message']}")
        for key, value in status.items():
            if key not in ("node", "level", "message"):
                print(f"        {key}: {value}")
    return 1 if any(s["level"] == "ERROR" for s in found) else 0


def _signed(args, text: str) -> str:
    """The payload signed as reviewer args.sign with its key from the key file (the version filled
    in first, since the signature covers it). With --raw it is signed but not validated, to show
    a node refusing a signed payload for what it says."""
    from lwm_models import messages, signing

    if not args.kind:
        raise ValueError("--sign needs --kind: the signature covers the message kind")
    payload = json.loads(text)
    if not isinstance(payload, dict):
        raise ValueError("only a JSON object can be signed")
    try:
        key = signing.load_private_key(args.keys_file, args.sign)
    except signing.KeyFileError as exc:
        fix = f"lwm ros keys --keys-file {args.keys_file} --reviewer {args.sign}"
        raise ValueError(f"{exc} (make one: {fix})") from None
    payload = signing.sign(args.kind, {"version": messages.version(args.kind), **payload}, args.sign, key)
    return json.dumps(payload)


def cmd_keys(args) -> int:
    """Create the key file, or add reviewers to it; prints who has a key, never the keys."""
    from lwm_models import signing

    keys = signing.ensure_key_file(args.keys_file, args.reviewer or signing.DEFAULT_REVIEWERS)
    here = sorted(r for r in keys if (signing.private_dir(args.keys_file) / f"{r}.key").exists())
    print(f"{args.keys_file}: public keys of {', '.join(sorted(keys))}; private keys here of {', '.join(here)}")
    return 0


def cmd_echo(node: Node, args) -> int:
    from rclpy.qos import QoSProfile
    from std_msgs.msg import String

    from lwm_nodes.common import EVENTS, LATCHED

    got = []
    done = threading.Event()

    def callback(msg: String) -> None:
        try:
            print(msg.data, flush=True)
        except BrokenPipeError:  # the reader went away (`| head`): nothing more to echo to
            closed.set()
            done.set()
            return
        got.append(msg.data)
        if args.count and len(got) >= args.count:
            done.set()

    closed = threading.Event()

    qos = LATCHED if args.latched else EVENTS
    if args.count > qos.depth:
        # A burst of messages (a recording played back fast) must not be thinned to the newest
        # while this process is busy printing: keep as many as are asked for.
        qos = QoSProfile(history=qos.history, depth=args.count, reliability=qos.reliability, durability=qos.durability)
    sub = node.create_subscription(String, args.topic, callback, qos)
    if args.wait_publishers:
        # Say when the publishers are matched, so that a caller can send what it wants to see
        # echoed then, rather than after a guessed sleep.
        deadline = time.monotonic() + (args.timeout if args.timeout > 0 else 30.0)
        while sub.get_publisher_count() < args.wait_publishers and time.monotonic() < deadline:
            time.sleep(0.02)
        print(f"# listening to {sub.get_publisher_count()} publisher(s) of {args.topic}", file=sys.stderr, flush=True)
    done.wait(args.timeout if args.timeout > 0 else None)
    if closed.is_set():
        # Python would flush stdout again at exit and fail on the closed pipe.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    return 0 if got or not args.count else 1


def cmd_call(node: Node, args) -> int:
    from lwm_interfaces.srv import Json

    client = node.create_client(Json, args.service)
    # Discovery finds a running server in well under a second: say at once when there is none.
    if not client.wait_for_service(timeout_sec=min(args.timeout, DISCOVERY_S)):
        print(f"lwm ros: error: nothing serves {args.service} (is the system running?)", file=sys.stderr)
        return 2
    request = Json.Request(request=_payload(args.payload, args.raw))
    response = client.call(request, timeout_sec=args.timeout)
    if response is None:
        print(f"lwm ros: error: {args.service} did not answer within {args.timeout} s", file=sys.stderr)
        return 2
    print(response.response)
    try:
        answer = json.loads(response.response)
    except ValueError:
        return 0
    if isinstance(answer, dict) and answer.get("ok") is False:
        print(f"lwm ros: {args.service} refused the request: {answer.get('error', 'no reason given')}", file=sys.stderr)
        return 1
    return 0


def cmd_play(node: Node, args) -> int:
    """Republish a recording's messages (their CDR bytes) with their original spacing / rate."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    from lwm_models import recording

    if args.rate <= 0:
        raise ValueError(f"--rate must be > 0, got {args.rate}")
    chosen = [m for m in recording.read(args.file) if not args.topics or m.topic in args.topics]
    publishers = {}
    for m in chosen:
        if m.topic not in publishers:
            durability = DurabilityPolicy.TRANSIENT_LOCAL if m.latched else DurabilityPolicy.VOLATILE
            qos = QoSProfile(
                history=HistoryPolicy.KEEP_LAST, depth=50, reliability=ReliabilityPolicy.RELIABLE, durability=durability
            )
            publishers[m.topic] = node.create_publisher(String, m.topic, qos)
    time.sleep(args.wait)  # let subscribers match before the first message
    began = time.monotonic()
    for m in chosen:
        due = began + (m.log_time_ns - chosen[0].log_time_ns) / 1e9 / args.rate
        time.sleep(max(0.0, due - time.monotonic()))
        publishers[m.topic].publish(recording.cdr_string(m.text))
    time.sleep(args.wait)  # acknowledgements, and latched messages for late subscribers
    print(f"played {len(chosen)} messages on {len(publishers)} topics")
    return 0


def cmd_record(args) -> int:
    """Run the recorder node in this process until --duration has passed or SIGINT/SIGTERM."""
    from lwm_nodes.common import run as run_node
    from lwm_nodes.recorder_node import RecorderNode

    stop = threading.Event()
    if args.duration > 0:
        threading.Timer(args.duration, stop.set).start()
    return run_node(lambda: RecorderNode(str(args.file)), stop)


HELP = "ROS 2 graph tools: nodes, topics, services, pub, echo, call, keys, record, play, diagnostics"
DESCRIPTION = "ROS 2 graph tools for the LWM system"


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="cmd", required=True)
    for what in ("nodes", "topics", "services"):
        s = sub.add_parser(what, help=f"list the graph's {what}")
        s.add_argument("--settle", type=float, default=1.0, help="seconds to wait for discovery")
    s = sub.add_parser("pub", help="publish one JSON message")
    s.add_argument("topic", help="topic name, e.g. /feedback/manual")
    s.add_argument("payload", help="JSON text, or @FILE")
    s.add_argument("--kind", default=None, help="validate against msgs_json/<kind>.schema.json first")
    s.add_argument("--latched", action="store_true", help="(the default) transient-local QoS, depth 1")
    s.add_argument("--volatile", action="store_true", help="volatile QoS instead of transient local")
    s.add_argument("--wait", type=float, default=2.0, help="seconds to wait for subscribers and acknowledgements")
    s.add_argument(
        "-w",
        "--wait-matching-subscriptions",
        type=int,
        default=1,
        metavar="N",
        help="publish once N subscribers are matched (or --wait has passed), as `ros2 topic pub -w N`",
    )
    s.add_argument("--raw", action="store_true", help="send the text as it is, even if it is not JSON")
    s.add_argument(
        "--sign",
        metavar="REVIEWER",
        default=None,
        help="sign as this reviewer (adds reviewer and signature; needs --kind): the planner and the world-model "
        "server take feedback only from reviewers they trust",
    )
    s.add_argument("--keys-file", type=Path, default=DEFAULT_KEYS, help="the reviewers' keys (default: %(default)s)")
    s.add_argument(
        "--ack-timeout",
        type=float,
        default=10.0,
        help="on /review/feedback, /review/labels and /feedback/manual: seconds to wait for the node's answer "
        "(exit 1 when it refuses, 3 when none comes; 0: do not wait)",
    )
    s = sub.add_parser("keys", help="create the reviewers' key file, or add reviewers to it")
    s.add_argument("--keys-file", type=Path, default=DEFAULT_KEYS, help="the key file (default: %(default)s)")
    s.add_argument(
        "--reviewer",
        nargs="+",
        default=None,
        help="reviewer ids that must have a key (default: scripted terminal); existing keys are kept",
    )
    s = sub.add_parser("echo", help="print the messages of a topic")
    s.add_argument("topic", help="topic name, e.g. /lwm/status")
    s.add_argument("--count", type=int, default=0, help="stop after N messages (0: until timeout)")
    s.add_argument("--timeout", type=float, default=10.0, help="seconds (0: forever)")
    s.add_argument("--latched", action="store_true", help="transient-local QoS, to get the last latched message")
    s.add_argument(
        "--wait-publishers",
        type=int,
        default=0,
        metavar="N",
        help="print '# listening ...' on stderr once N publishers are matched (or the timeout passed)",
    )
    s = sub.add_parser("call", help="call a JSON service")
    s.add_argument("service", help="service name, e.g. /lwm/imagine")
    s.add_argument("payload", help="JSON text, or @FILE")
    s.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for the service and its answer")
    s.add_argument("--raw", action="store_true", help="send the text as it is, even if it is not JSON")
    s = sub.add_parser("record", help="record every topic to an MCAP file (Foxglove and rosbag2 open it)")
    s.add_argument("file", type=Path, help="the MCAP file to write")
    s.add_argument("--duration", type=float, default=0.0, help="seconds to record (0: until SIGINT/SIGTERM)")
    s = sub.add_parser("play", help="republish the messages of an MCAP recording")
    s.add_argument("file", type=Path, help="an MCAP file from `lwm ros record` or `./run_nodes.sh --record`")
    s.add_argument("--rate", type=float, default=1.0, help="speed-up of the recorded timing (2: twice as fast)")
    s.add_argument("--topics", nargs="+", default=None, help="play only these topics (default: all)")
    s.add_argument("--wait", type=float, default=1.0, help="seconds to let subscribers match, before and after")

    s = sub.add_parser("diagnostics", help="each node's latest report on /diagnostics")
    s.add_argument("--seconds", type=float, default=3.0, help="how long to listen (the nodes report every second)")
    s.add_argument("--json", action="store_true", help="one JSON object per node instead of the table")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="lwm ros", description=DESCRIPTION)
    add_arguments(p)
    return p


def register(subparsers: argparse._SubParsersAction) -> None:
    """Adds `ros` to `lwm` (the entry point in the group lwm_models.commands)."""
    p = subparsers.add_parser("ros", help=HELP, description=DESCRIPTION)
    add_arguments(p)
    p.set_defaults(func=run)


def _interrupt(*_) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


def run(args: argparse.Namespace) -> int:
    try:
        import rclpy
        from rclpy.signals import SignalHandlerOptions

        from lwm_nodes.common import ros_environment
    except ImportError as exc:  # lwm_nodes is installed, but not ROS 2 itself
        print(f"lwm ros: error: ROS 2 is not available ({exc}); run ./run_nodes.sh once", file=sys.stderr)
        return 2
    from lwm_models import messages, signing
    from lwm_models.errors import LwmError

    if args.cmd == "record":  # the recorder node, run as a node of its own
        return cmd_record(args)
    if args.cmd == "keys":  # no ROS needed
        try:
            return cmd_keys(args)
        except (OSError, signing.SigningError) as exc:
            print(f"lwm ros: error: {exc}", file=sys.stderr)
            return 2
    ros_environment()
    # rclpy's handlers would shut the context down under the spinning thread; SIGINT and SIGTERM
    # end the command through KeyboardInterrupt instead, so the node is torn down in order.
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    signal.signal(signal.SIGTERM, _interrupt)
    node = rclpy.create_node(f"lwm_cli_{int(time.time() * 1000) % 100000}")
    spinner = BackgroundSpin(node)
    try:
        if args.cmd in ("nodes", "topics", "services"):
            return cmd_graph(node, args.cmd, args.settle)
        commands = {
            "pub": cmd_pub,
            "echo": cmd_echo,
            "call": cmd_call,
            "play": cmd_play,
            "diagnostics": cmd_diagnostics,
        }
        return commands[args.cmd](node, args)
    except (OSError, ValueError, messages.MessageError, signing.SigningError, LwmError) as exc:
        print(f"lwm ros: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    finally:
        spinner.close()
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    raise SystemExit(main())
