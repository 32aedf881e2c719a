"""MCAP recordings (lwm_models.recording): what is written reads back, ROS 2's own serializer agrees
with the CDR here, and the mcap-ros2 decoder (what other ROS tools use) opens the files. The
recording of a real review is tested in test_scripted_runs.py."""

from __future__ import annotations

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from lwm_models import recording
from lwm_models.recording import Recorder, RecordingError, cdr_string, string_of_cdr

TEXTS = ['{"version": 1, "ok": true}', "δ → ünïcode ✓", "", "x" * 100_000]


def write(path, messages):
    rec = Recorder(path)
    for topic, latched, text, t in messages:
        rec.add_topic(topic, latched)
        rec.write(topic, cdr_string(text), t)
    rec.close()
    return rec


def test_a_recording_reads_back_in_time_order(tmp_path):
    path = tmp_path / "r.mcap"
    messages = [
        ("/lwm/status", True, TEXTS[0], 3_000),
        ("/lwm/errors", False, TEXTS[1], 1_000),
        ("/lwm/status", True, TEXTS[2], 2_000),
        ("/planner/plan", True, TEXTS[3], 4_000),
    ]
    rec = write(path, messages)
    assert rec.counts == {"/lwm/status": 2, "/lwm/errors": 1, "/planner/plan": 1}
    got = list(recording.read(path))
    assert [(m.topic, m.text, m.log_time_ns, m.latched) for m in got] == [
        (t, text, ns, latched) for t, latched, text, ns in sorted(messages, key=lambda m: m[3])
    ]


def test_ros2_tools_decode_the_file(tmp_path):
    # The same decoder Foxglove's and rosbag2's MCAP readers implement: schema std_msgs/msg/String
    # in ros2msg, messages in CDR, profile ros2.
    path = tmp_path / "r.mcap"
    write(path, [("/a", True, text, i) for i, text in enumerate(TEXTS)])
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        decoded = [(c.topic, s.name, m.data) for s, c, _, m in reader.iter_decoded_messages()]
        summary = reader.get_summary()
    assert decoded == [("/a", "std_msgs/msg/String", text) for text in TEXTS]
    (channel,) = summary.channels.values()
    assert "durability: transient_local" in channel.metadata["offered_qos_profiles"]


def test_the_cdr_is_what_ros2_serializes():
    rclpy_serialization = pytest.importorskip("rclpy.serialization")
    from std_msgs.msg import String

    for text in TEXTS:
        wire = rclpy_serialization.serialize_message(String(data=text))
        assert cdr_string(text) == wire
        assert string_of_cdr(wire) == text


def test_files_that_are_not_recordings_get_a_clear_error(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_text("not an mcap file")
    for path, words in ((bad, "not an MCAP recording"), (tmp_path / "missing.mcap", "cannot read the recording")):
        with pytest.raises(RecordingError, match=words):
            list(recording.read(path))
    with pytest.raises(RecordingError):
        string_of_cdr(b"\x00\x01\x00\x00\xff\x00\x00\x00abc")
