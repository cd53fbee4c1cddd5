"""Which topic feeds which sensor, and why every other topic is left unread.

Order of authority:

1. ``reader.sensors`` (the configuration): exactly those sensors, nothing else is read.
2. The mission's sidecar (our simulator's, or one a user wrote): its sensors and topics; a sensor
   whose topic is not in the bag is left out (``BindingPlan.absent``; the mission check names it).
3. For each sensor kind the sidecar does not bind, **one topic chosen by this rule**, among the
   topics whose message type feeds that kind (``conversions.CODECS``):

   a. a topic without messages, or an ``Imu`` topic whose first messages carry no orientation
      (REP 145: a raw IMU), is no candidate;
   b. a topic whose name says it is not the vehicle's sensor (a part ``leak``, ``housing``,
      ``internal``, ``battery``, ``hull``, ``enclosure``, ``bottle``, ``canister``, ``board``,
      ``cpu``, ``ambient``, ``air``; for an AHRS also ``raw``) comes after those that do not;
   c. then the richer message type: for a DVL, a vendor message with validity (COLA2, UUV
      Simulator, Water Linked) before a bare ``TwistWithCovarianceStamped``; for GPS,
      ``NavSatFix`` before ``GPSFix``;
   d. then more messages (the higher rate), then the topic name.

   ``nav_msgs/Odometry`` is never chosen: in a real recording it is the vehicle's own navigation,
   not ground truth. It is ground truth only when the sidecar says so or the user binds it.

A sensor chosen by the rule is named after its topic ('/nav/dvl' → 'nav/dvl'). Every topic that
is not read is listed with the reason (an alternative candidate, Odometry, a message type no
sensor reads, an unknown type), and ``semslam info MISSION --write-config F`` writes the binding
as YAML with the alternatives commented out.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from semslam.errors import MissionError
from semslam.mission.codec_base import short_msgtype
from semslam.mission.config import ReaderConfig
from semslam.mission.conversions import CODECS, Codec
from semslam.mission.mission import SENSOR_KINDS, MissionMetadata
from semslam.mission.probe import TopicProbe

SUPPORTED = ", ".join(short_msgtype(t) for t in CODECS)
HOUSEKEEPING_WORDS = frozenset(
    "leak housing internal battery hull enclosure bottle canister board cpu ambient air".split()
)
_TYPE_RANK = {
    "geometry_msgs/msg/TwistWithCovarianceStamped": 1,
    "gps_msgs/msg/GPSFix": 1,
    "gps_common/msg/GPSFix": 1,
}
NEVER_CHOSEN = {"ground_truth"}
# Why an alternative lost, by the first criterion of the rank that tells it from the chosen topic.
_LOST_ON = (
    "its name says it is not the vehicle's sensor",
    "a plainer message type",
    "fewer messages",
    "name order",
)


@dataclass(frozen=True)
class Binding:
    """One sensor read from one topic."""

    sensor: str
    kind: str
    topic: str
    msgtype: str  # normalised
    codec: Codec
    origin: str = "chosen"  # configured | sidecar | chosen
    stamp: str | None = None  # the sensor's own stamp policy (configured), else reader.stamp


@dataclass(frozen=True)
class Unread:
    """A topic that is not read, and why."""

    topic: str
    msgtype: str | None  # short form, None when the topic carries several types
    reason: str
    kind: str | None = None  # the sensor kind it could feed (an alternative, Odometry)
    count: int = 0


@dataclass(frozen=True)
class Absent:
    """A sensor the sidecar declares whose topic the bag does not hold (a bag cut down, a sensor off)."""

    sensor: str
    kind: str
    topic: str


@dataclass
class BindingPlan:
    bindings: list[Binding]
    unread: list[Unread] = field(default_factory=list)
    absent: list[Absent] = field(default_factory=list)  # the sidecar's sensors with no topic in the bag

    def alternatives(self, kind: str) -> list[Unread]:
        return [u for u in self.unread if u.kind == kind]


def _words(topic: str) -> set[str]:
    return set(re.split(r"[^a-z0-9]+", topic.lower())) - {""}


def _rank(topic: str, kind: str, msgtype: str, count: int) -> tuple:
    words = _words(topic)
    demoted = bool(words & HOUSEKEEPING_WORDS) or (kind == "ahrs" and "raw" in words)
    return (demoted, _TYPE_RANK.get(msgtype, 0), -count, topic)


def _not_a_candidate(probe: TopicProbe | None, count: int) -> str | None:
    if count == 0:
        return "no messages"
    if probe is not None and probe.n and probe.without_orientation == probe.n:
        return "Imu without orientation (orientation_covariance[0] = -1, REP 145): a raw IMU, not an AHRS"
    return None


def plan_bindings(
    path: Path,
    topics: dict[str, str | None],
    counts: dict[str, int],
    known_types: set[str],
    cfg: ReaderConfig,
    side: MissionMetadata | None,
    probes: dict[str, TopicProbe],
) -> BindingPlan:
    """The binding of ``path``'s topics (topic → normalised message type, None if several)."""

    def binding(sensor: str, kind: str, topic: str, origin: str, stamp=None) -> Binding:
        if topic not in topics:
            raise MissionError(
                f"{path}: topic {topic} ({origin} sensor {sensor!r}) is not in the bag "
                f"(topics: {', '.join(sorted(topics)) or 'none'})"
            )
        if kind not in SENSOR_KINDS:
            raise MissionError(
                f"{path}: {origin} sensor {sensor!r}: unknown kind {kind!r} (expected {', '.join(SENSOR_KINDS)})"
            )
        msgtype = topics[topic]
        if msgtype is None:
            raise MissionError(f"{path}: topic {topic} carries several message types")
        codec = CODECS.get(msgtype)
        if codec is None:
            raise MissionError(
                f"{path}: topic {topic}: message type {short_msgtype(msgtype)} is not supported "
                f"(supported: {SUPPORTED})"
            )
        # A scan is a scan: point clouds and swaths may come from a laser or a sonar.
        if kind != codec.kind and not {kind, codec.kind} <= {"laser", "sonar"}:
            raise MissionError(
                f"{path}: topic {topic}: {short_msgtype(msgtype)} feeds a {codec.kind} sensor, "
                f"but {origin} sensor {sensor!r} is of kind {kind}"
            )
        return Binding(sensor, kind, topic, msgtype, codec, origin, stamp)

    if cfg.sensors:
        bound = [binding(name, tb.kind, tb.topic, "configured", tb.stamp) for name, tb in cfg.sensors.items()]
        return BindingPlan(bound, _unread(topics, counts, known_types, bound, {}, "not in reader.sensors"))
    bound = []
    absent = []
    if side is not None:  # a sensor whose topic is not in the bag is left out (semslam.mission.check says so)
        bound = [binding(s.name, s.kind, s.topic, "sidecar") for s in side.sensors.values() if s.topic in topics]
        absent = [Absent(s.name, s.kind, s.topic) for s in side.sensors.values() if s.topic and s.topic not in topics]
    taken = {b.topic for b in bound}
    names = {b.sensor for b in bound}
    kinds_bound = {b.kind for b in bound}
    why_not: dict[str, tuple[str, str]] = {}  # topic → (kind, reason)
    candidates: dict[str, list[str]] = {}
    for topic, msgtype in sorted(topics.items()):
        codec = CODECS.get(msgtype) if msgtype else None
        if topic in taken or codec is None:
            continue
        if codec.kind in NEVER_CHOSEN:
            why_not[topic] = (
                codec.kind,
                "the vehicle's own navigation, not ground truth "
                "(bind it with kind ground_truth in reader.sensors to use it as such)",
            )
            continue
        problem = _not_a_candidate(probes.get(topic), counts.get(topic, 0))
        if problem:
            why_not[topic] = (codec.kind, problem)
            continue
        candidates.setdefault(codec.kind, []).append(topic)
    for kind, tops in candidates.items():
        if kind in kinds_bound:
            chosen = next(b.topic for b in bound if b.kind == kind)
            for t in tops:
                why_not[t] = (kind, f"alternative {kind}: the sidecar binds {chosen}")
            continue
        ranked = sorted(tops, key=lambda t: _rank(t, kind, topics[t], counts.get(t, 0)))
        best = ranked[0]
        name = best.lstrip("/") or best
        if name in names:
            name = best
        names.add(name)
        bound.append(Binding(name, kind, best, topics[best], CODECS[topics[best]], "chosen"))
        top = _rank(best, kind, topics[best], counts.get(best, 0))
        for t in ranked[1:]:
            mine = _rank(t, kind, topics[t], counts.get(t, 0))
            lost = next(_LOST_ON[i] for i in range(len(top)) if mine[i] != top[i])
            why_not[t] = (kind, f"alternative {kind} (chosen: {best}; this one: {lost})")
    return BindingPlan(bound, _unread(topics, counts, known_types, bound, why_not, None), absent)


def _unread(
    topics: dict[str, str | None],
    counts: dict[str, int],
    known_types: set[str],
    bound: list[Binding],
    why_not: dict[str, tuple[str, str]],
    default_reason: str | None,
) -> list[Unread]:
    taken = {b.topic for b in bound}
    out = []
    for topic, msgtype in sorted(topics.items()):
        if topic in taken:
            continue
        n = counts.get(topic, 0)
        if msgtype is None:
            out.append(Unread(topic, None, "carries several message types", count=n))
            continue
        short = short_msgtype(msgtype)
        codec = CODECS.get(msgtype)
        if topic in why_not:
            kind, reason = why_not[topic]
            out.append(Unread(topic, short, reason, kind, n))
        elif codec is not None:
            out.append(Unread(topic, short, default_reason or "not bound", codec.kind, n))
        elif msgtype not in known_types:
            out.append(Unread(topic, short, "unknown message type (no definition in the bag or shipped)", count=n))
        else:
            out.append(Unread(topic, short, "no sensor kind reads this message type", count=n))
    return out
