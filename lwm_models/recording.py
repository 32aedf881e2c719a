"""Recordings of the system's topics as MCAP files, the format of rosbag2's MCAP storage and of
Foxglove (https://mcap.dev/spec, profile "ros2").

Every topic of the system carries `std_msgs/msg/String`, so a recording holds one schema (the
message definition `string data`, encoding `ros2msg`) and, per topic, a channel whose messages are
the CDR bytes as they came off the wire. Writing keeps those bytes untouched; reading decodes the
CDR string here, which is all a String needs (an encapsulation header, a length, the UTF-8 bytes
and a NUL). A channel's metadata carries the QoS its publishers offered, in rosbag2's form, so
that a player can publish latched topics as latched.

No ROS here: the recorder node and `lwm ros play` are the adapters.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from .errors import LwmError

STRING_TYPE = "std_msgs/msg/String"
STRING_DEFINITION = b"string data"
# A service call's event (service introspection, <service>/_service_event): its definition with
# the types it uses, in rosbag2's form (each after a line of 80 '=' and "MSG: pkg/Type").
EVENT_TYPE = "lwm_interfaces/srv/Json_Event"
_RULE = "=" * 80
EVENT_DEFINITION = f"""service_msgs/ServiceEventInfo info
Json_Request[<=1] request
Json_Response[<=1] response
{_RULE}
MSG: service_msgs/ServiceEventInfo
uint8 REQUEST_SENT = 0
uint8 REQUEST_RECEIVED = 1
uint8 RESPONSE_SENT = 2
uint8 RESPONSE_RECEIVED = 3
uint8 event_type
builtin_interfaces/Time stamp
char[16] client_gid
int64 sequence_number
{_RULE}
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
{_RULE}
MSG: lwm_interfaces/Json_Request
string request
{_RULE}
MSG: lwm_interfaces/Json_Response
string response
""".encode()
DEFINITIONS = {STRING_TYPE: STRING_DEFINITION, EVENT_TYPE: EVENT_DEFINITION}
_CDR_LE = b"\x00\x01\x00\x00"  # encapsulation: plain CDR, little endian


class RecordingError(LwmError):
    """A file that is not a recording of this system (or not an MCAP file)."""


@dataclass(frozen=True)
class Message:
    topic: str
    text: str
    log_time_ns: int  # when the recorder received it
    latched: bool  # its publishers offered transient-local durability


def cdr_string(text: str) -> bytes:
    """The CDR serialization of a std_msgs/String (what rmw puts on the wire)."""
    data = text.encode() + b"\x00"
    return _CDR_LE + struct.pack("<I", len(data)) + data


def string_of_cdr(data: bytes) -> str:
    if len(data) < 8 or data[:2] != _CDR_LE[:2]:
        raise RecordingError("not a little-endian CDR std_msgs/String")
    (n,) = struct.unpack_from("<I", data, 4)
    if n < 1 or 8 + n > len(data):
        raise RecordingError("a CDR string's length runs past its message")
    return data[8 : 8 + n - 1].decode()


def qos_metadata(latched: bool) -> str:
    """A channel's `offered_qos_profiles`, as rosbag2 writes them (YAML)."""
    durability = "transient_local" if latched else "volatile"
    return (
        "- history: keep_last\n  depth: 1\n  reliability: reliable\n"
        f"  durability: {durability}\n"
        "  deadline:\n    sec: 2147483647\n    nsec: 4294967295\n"
        "  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n"
        "  liveliness: automatic\n"
        "  liveliness_lease_duration:\n    sec: 2147483647\n    nsec: 4294967295\n"
        "  avoid_ros_namespace_conventions: false"
    )


class Recorder:
    """Writes messages to an MCAP file; `close` writes its index and footer."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: BinaryIO = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        self._writer = Writer(self._file, compression=CompressionType.NONE)
        self._writer.start(profile="ros2", library="lwm_models.recording")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        self._closed = False

    def add_topic(self, topic: str, latched: bool, kind: str = STRING_TYPE) -> None:
        """A channel for a topic of one of DEFINITIONS' types (a String topic, or a service's events)."""
        if kind not in self._schemas:
            self._schemas[kind] = self._writer.register_schema(name=kind, encoding="ros2msg", data=DEFINITIONS[kind])
        if topic not in self._channels:
            self._channels[topic] = self._writer.register_channel(
                topic=topic,
                message_encoding="cdr",
                schema_id=self._schemas[kind],
                metadata={"offered_qos_profiles": qos_metadata(latched)},
            )
            self.counts[topic] = 0

    def write(self, topic: str, cdr: bytes, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        """One message (CDR bytes) on a topic added before."""
        if self._closed:
            return
        self._writer.add_message(
            channel_id=self._channels[topic],
            log_time=log_time_ns,
            publish_time=log_time_ns if publish_time_ns is None else publish_time_ns,
            data=cdr,
            sequence=self.counts[topic],
        )
        self.counts[topic] += 1

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._writer.finish()
            self._file.close()


def read(path: str | Path) -> Iterator[Message]:
    """The String messages of a recording in the order they were received (a service's events,
    recorded beside them, are left out: `lwm ros play` republishes topics)."""
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            for schema, channel, message in reader.iter_messages(log_time_order=True):
                if schema is not None and schema.name == EVENT_TYPE:
                    continue
                if schema is None or schema.name != STRING_TYPE or channel.message_encoding != "cdr":
                    raise RecordingError(f"{channel.topic}: not a {STRING_TYPE} channel in CDR")
                latched = "transient_local" in channel.metadata.get("offered_qos_profiles", "")
                yield Message(channel.topic, string_of_cdr(message.data), message.log_time, latched)
    except OSError as exc:
        raise RecordingError(f"cannot read the recording {path}: {exc.strerror or exc}") from None
    except RecordingError:
        raise
    except Exception as exc:  # the mcap reader's errors for a file that is not MCAP
        raise RecordingError(f"{path} is not an MCAP recording: {exc}") from None


__all__ = ["EVENT_TYPE", "Message", "Recorder", "RecordingError", "cdr_string", "read", "string_of_cdr"]
