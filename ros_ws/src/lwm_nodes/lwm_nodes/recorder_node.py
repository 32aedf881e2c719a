"""Recorder node: every topic of the system, as it comes off the wire, into an MCAP file
(lwm_models.recording), which Foxglove and rosbag2's MCAP storage open.

It discovers topics as they appear (every `discovery_period` seconds) and subscribes to each
std_msgs/String topic raw, so a message is stored as the CDR bytes its publisher sent; and to each
service's events (lwm_interfaces/srv/Json_Event on <service>/_service_event: every request and
response, published by the nodes when the launcher records, parameter service_introspection). A topic
whose publishers are all transient-local (the latched state topics, the kept feedback) is
subscribed transient-local, so that what was published before the subscription matched is still
delivered; the others volatile (a transient-local subscription would not match them). The launcher
starts it first (`./run_nodes.sh --record FILE`); on SIGINT/SIGTERM it writes the file's index and
footer before it exits.
"""

from __future__ import annotations

from lwm_interfaces.srv import Json
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from lwm_models.recording import EVENT_TYPE, STRING_TYPE, Recorder
from lwm_nodes.common import JsonNode, run

DEPTH = 100  # per topic: what a transient-local publisher may hand over at once is at most 50


class RecorderNode(JsonNode):
    def __init__(self, path: str = "recording.mcap") -> None:
        """`path`: the default of the parameter `path` (`lwm ros record FILE` gives it)."""
        super().__init__("lwm_recorder")
        path = self.declare_parameter("path", path).value
        period = float(self.declare_parameter("discovery_period", 0.2).value)
        self.recorder = Recorder(path)
        self.subscriptions_by_topic: dict[str, object] = {}
        self.create_timer(period, self.discover)
        self.discover()
        self.get_logger().info(f"recording to {path}")

    def discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            kind = next((t for t in (STRING_TYPE, EVENT_TYPE) if t in types), None)
            if topic in self.subscriptions_by_topic or kind is None:
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue  # subscribed once a publisher shows which durability it offers
            latched = all(p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in publishers)
            qos = QoSProfile(
                history=HistoryPolicy.KEEP_LAST,
                depth=DEPTH,
                reliability=ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
            )
            self.recorder.add_topic(topic, latched, kind)
            message_type = String if kind == STRING_TYPE else Json.Event
            self.subscriptions_by_topic[topic] = self.create_subscription(
                message_type, topic, lambda data, topic=topic: self.on_message(topic, data), qos, raw=True
            )
            self.get_logger().info(f"recording {topic} ({'latched' if latched else 'volatile'})")

    def health(self) -> tuple[str, dict[str, object]]:
        written = sum(self.recorder.counts.values())
        return f"recording {len(self.subscriptions_by_topic)} topics to {self.recorder.path}", {"messages": written}

    def on_message(self, topic: str, data: bytes) -> None:
        self.recorder.write(topic, data, self.get_clock().now().nanoseconds)

    def close(self) -> None:
        self.recorder.close()
        counts = ", ".join(f"{t} {n}" for t, n in sorted(self.recorder.counts.items()))
        self.get_logger().info(f"recorded {sum(self.recorder.counts.values())} messages: {counts}")


def main() -> int:
    return run(RecorderNode)


if __name__ == "__main__":
    raise SystemExit(main())
