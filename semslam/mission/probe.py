"""A first look at a bag's sensor topics before they are read: the first messages of each.

For every topic of a message type semslam reads, up to ``PROBE_MESSAGES`` messages are looked at
(point clouds and scans, whose messages are large: ``PROBE_SCANS``, and only for the topics read): their header stamps (read
from the raw bytes: every supported message starts with a std_msgs/Header) beside the recorder's
receive times, and, for Imu topics, whether they carry an orientation at all. The stamp policy
(``semslam.mission.stamps``) and the choice of one topic per sensor kind
(``semslam.mission.binding``) are decided from this.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

PROBE_MESSAGES = 64
PROBE_SCANS = 3
LARGE = {"sensor_msgs/msg/PointCloud2", "sensor_msgs/msg/LaserScan"}
_IMU = "sensor_msgs/msg/Imu"
_TIME_LE = struct.Struct("<iI")
_TIME_BE = struct.Struct(">iI")


@dataclass
class TopicProbe:
    """What the first messages of one topic showed."""

    topic: str
    msgtype: str  # normalised
    header: list[int] = field(default_factory=list)  # header stamps (ns)
    receive: list[int] = field(default_factory=list)  # the recorder's receive times (ns)
    without_orientation: int = 0  # Imu messages whose orientation covariance is marked -1 (REP 145)

    @property
    def n(self) -> int:
        return len(self.header)


def header_stamp(raw, ros_version: int) -> int | None:
    """The std_msgs/Header stamp at the start of a serialized message (ns), None if too short.
    ROS 1: seq (uint32) then stamp; ROS 2 (CDR): 4-byte encapsulation header, then stamp."""
    if len(raw) < 12:
        return None
    if ros_version == 1:
        sec, nanosec = _TIME_LE.unpack_from(raw, 4)
    else:
        sec, nanosec = (_TIME_LE if raw[1] == 1 else _TIME_BE).unpack_from(raw, 4)
    return sec * 1_000_000_000 + nanosec


def probe_topics(reader, topics: dict[str, str], ros_version: int) -> dict[str, TopicProbe]:
    """``topics``: topic → normalised message type (those to probe). ``reader``: an open AnyReader."""
    out: dict[str, TopicProbe] = {}
    by_topic: dict[str, list] = {}
    for c in reader.connections:
        if c.topic in topics:
            by_topic.setdefault(c.topic, []).append(c)
    for topic, conns in by_topic.items():
        msgtype = topics[topic]
        p = out[topic] = TopicProbe(topic, msgtype)
        limit = PROBE_SCANS if msgtype in LARGE else PROBE_MESSAGES
        try:
            for conn, t_bag, raw in reader.messages(connections=conns):
                stamp = header_stamp(raw, ros_version)
                if stamp is None:
                    break
                p.header.append(stamp)
                p.receive.append(t_bag)
                if msgtype == _IMU and _imu_without_orientation(reader, raw, conn.msgtype):
                    p.without_orientation += 1
                if p.n >= limit:
                    break
        except Exception:  # a damaged bag: the read itself reports it, with the file and topic
            continue
    return out


def _imu_without_orientation(reader, raw, msgtype: str) -> bool:
    try:
        return float(reader.deserialize(raw, msgtype).orientation_covariance[0]) == -1.0
    except Exception:  # malformed: the read reports it
        return False
