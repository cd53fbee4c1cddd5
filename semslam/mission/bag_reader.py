"""Reading a ROS 1 ``.bag``, a ROS 2 bag directory (sqlite3 or mcap storage) or a ``.mcap`` file.

What is cheap is checked when the mission is opened (the path exists and is a bag, the bag opens
and its index reads, every configured topic exists with a supported message type, the sidecar is
valid); what needs the messages (corrupt chunks, malformed or non-finite messages, stamps going
backwards) is found while streaming. Every such problem is a ``MissionError`` with one line naming
the file, topic and field.

Streaming: messages come from the bag in recording-time order; measurements are released in
header-stamp order through a reorder buffer: a measurement is released once a message stamped
``ReaderConfig.reorder_window_s`` later has arrived, so sensors with different latencies still
interleave correctly (the window is in header-stamp time, so it does not matter whether the
recording clock is the same as the stamps' — wall time vs simulated time). A header stamp of
0 (driver did not fill it) is replaced by the recording time.
"""

from __future__ import annotations

import dataclasses
import heapq
from collections import Counter, defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semslam.errors import MissionError
from semslam.mission import sidecar
from semslam.mission.config import ReaderConfig
from semslam.mission.conversions import (
    CODECS,
    ROS1_FAST,
    Codec,
    MalformedMessage,
    Ros1Fast,
    Unusable,
    normalize_msgtype,
    short_msgtype,
    stamp_ns,
)
from semslam.mission.measurements import Measurement
from semslam.mission.mission import SENSOR_KINDS, Mission, MissionMetadata, SensorInfo
from semslam.mission.typestore import add_missing_types, typestore

SUPPORTED = ", ".join(short_msgtype(t) for t in CODECS)


@dataclass(frozen=True)
class Binding:
    """One sensor read from one topic."""

    sensor: str
    kind: str
    topic: str
    msgtype: str  # normalised
    codec: Codec


class BagMission(Mission):
    """A Mission streamed from a bag. Adds what ``semslam info`` reports beyond ``Mission``.

    ``dropped`` (sensor → count) and ``dropped_fields`` (sensor → field → count) are those of the
    last complete pass over the bag; ``message_counts`` (topic → count) come from the bag's index.
    """

    def __init__(
        self,
        metadata: MissionMetadata,
        path: Path,
        bindings: list[Binding],
        config: ReaderConfig,
        ros_version: int,
        message_counts: dict[str, int],
    ):
        super().__init__(metadata, self._stream)
        self.path = path
        self.bindings = bindings
        self.config = config
        self.ros_version = ros_version
        self.message_counts = message_counts
        self.dropped_fields: dict[str, Counter[str]] = {}

    @property
    def message_count(self) -> int:
        """Messages on the bound topics (from the index): the length of a full pass, for progress bars."""
        return sum(self.message_counts.get(b.topic, 0) for b in self.bindings)

    def _stream(self) -> Iterator[Measurement]:
        cfg = self.config
        window = int(cfg.reorder_window_s * 1e9)
        by_topic = {b.topic: b for b in self.bindings}
        dropped: Counter[str] = Counter()
        fields: dict[str, Counter[str]] = defaultdict(Counter)
        last_stamp: dict[str, int] = {}
        released = -(2**63)
        newest = -(2**63)
        heap: list[tuple[int, int, Measurement]] = []
        seq = 0
        with open_bag(self.path) as reader:
            conns = [c for c in reader.connections if c.topic in by_topic]
            fast = _fast_paths(reader, conns, self.ros_version)
            where = {t: f"{self.path}: topic {t}" for t in by_topic}  # every error's prefix, per topic
            messages = reader.messages(connections=conns)
            while True:
                try:
                    item = next(messages, None)
                except Exception as exc:  # a damaged chunk / page / record: any rosbags or storage error
                    raise MissionError(f"{self.path}: corrupt or truncated bag ({_one_line(exc)})") from None
                if item is None:
                    break
                conn, t_bag, raw = item
                b = by_topic[conn.topic]
                f = fast.get(b.topic)
                parsed = f.parse(raw) if f is not None else None
                if parsed is None:
                    try:
                        msg = reader.deserialize(raw, conn.msgtype)
                    except Exception as exc:
                        raise MissionError(
                            f"{where[b.topic]}: message at t={t_bag * 1e-9:.6f} s cannot be decoded as "
                            f"{short_msgtype(conn.msgtype)} ({_one_line(exc)})"
                        ) from None
                    header_stamp = stamp_ns(msg.header)
                else:
                    header_stamp, values = parsed
                stamp = header_stamp or t_bag
                if stamp < last_stamp.get(b.topic, stamp):
                    raise MissionError(
                        f"{where[b.topic]}: header stamps go backwards ({stamp * 1e-9:.6f} s after "
                        f"{last_stamp[b.topic] * 1e-9:.6f} s)"
                    )
                last_stamp[b.topic] = stamp
                try:
                    if parsed is None:
                        m = b.codec.decode(msg, b.sensor, cfg)
                    else:
                        m = f.build(header_stamp, values, b.sensor, cfg)
                except MalformedMessage as exc:
                    raise MissionError(f"{where[b.topic]}: {exc} (message at t={stamp * 1e-9:.6f} s)") from None
                except Unusable as exc:  # e.g. an Imu without orientation: no AHRS reading in it
                    dropped[b.sensor] += 1
                    fields[b.sensor][exc.field] += 1
                    continue
                if m.stamp != stamp:
                    m = dataclasses.replace(m, stamp=stamp)
                bad = m.nonfinite_field()
                if bad is not None:
                    if cfg.on_nonfinite == "error":
                        raise MissionError(
                            f"{where[b.topic]}: field {bad} is not finite (message at t={stamp * 1e-9:.6f} s)"
                        )
                    dropped[b.sensor] += 1
                    fields[b.sensor][bad] += 1
                    continue
                if stamp < released:
                    raise MissionError(
                        f"{where[b.topic]}: message stamped {stamp * 1e-9:.6f} s arrived after messages stamped more "
                        f"than reorder_window_s={cfg.reorder_window_s} s later (raise reorder_window_s)"
                    )
                heapq.heappush(heap, (stamp, seq, m))
                seq += 1
                newest = max(newest, stamp)
                horizon = newest - window
                while heap and heap[0][0] <= horizon:
                    released, _, out = heapq.heappop(heap)
                    yield out
            while heap:
                yield heapq.heappop(heap)[2]
        self.dropped.clear()
        self.dropped.update(dropped)
        self.dropped_fields = dict(fields)


def _fast_paths(reader, conns, ros_version: int) -> dict[str, Ros1Fast]:
    """Topic → the fast path of its message type (ROS 1 only), where the bag's definition of that
    type, nested types included, is the standard one that the fast path reads."""
    if ros_version != 1:
        return {}
    standard = typestore(1)
    out = {}
    for c in conns:
        f = ROS1_FAST.get(normalize_msgtype(c.msgtype))
        try:
            if f is not None and _layout(reader.typestore, c.msgtype) == _layout(
                standard, normalize_msgtype(c.msgtype)
            ):
                out[c.topic] = f
        except KeyError:  # a type the store does not know: the general path says what is wrong
            pass
    return out


def _layout(store, typename: str) -> tuple:
    """The fields of ``typename`` with every nested type replaced by its own fields, recursively."""
    from rosbags.typesys.base import Nodetype

    def walk(d):
        if isinstance(d, tuple):
            if len(d) == 2 and d[0] == Nodetype.NAME and isinstance(d[1], str):
                return (Nodetype.NAME, _layout(store, d[1]))
            return tuple(walk(x) for x in d)
        return d

    return walk(tuple(store.fielddefs[typename][1]))


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())  # one line, whatever the library put in it
    name = type(exc).__name__
    if name.endswith("ReaderError"):  # rosbags' own messages say what is wrong; the class adds nothing
        return text or name
    return f"{name}: {text}" if text else name


def bag_kind(path: Path) -> int:
    """1 or 2 (ROS version) for something that looks like a bag, else MissionError naming the path."""
    if not path.exists():
        raise MissionError(f"{path}: no such file or directory")
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            raise MissionError(f"{path}: directory is not a ROS 2 bag (no metadata.yaml)")
        return 2
    if path.suffix == ".bag":
        return 1
    if path.suffix in (".mcap", ".db3"):
        return 2
    raise MissionError(f"{path}: not a bag (expected a ROS 1 .bag, a ROS 2 bag directory or a .mcap file)")


@contextmanager
def open_bag(path: Path):
    """An open rosbags ``AnyReader`` whose type store also knows the standard and shipped types."""
    from rosbags.highlevel import AnyReader

    version = bag_kind(path)
    try:
        reader = AnyReader([path], default_typestore=typestore(version))
        reader.open()
        add_missing_types(reader.typestore, version, {c.msgtype for c in reader.connections})
    except MissionError:
        raise
    except Exception as exc:  # what a damaged / foreign file raises varies: sqlite3, struct, yaml, rosbags...
        raise MissionError(f"{path}: cannot open bag, corrupt or truncated? ({_one_line(exc)})") from None
    try:
        yield reader
    finally:
        try:
            reader.close()
        except Exception:  # closing a damaged bag must not hide the real error
            pass


def _bind(path: Path, topics: dict[str, str | None], cfg: ReaderConfig, side: MissionMetadata | None) -> list[Binding]:
    """Which sensor reads which topic: the configuration, else the sidecar + discovery by message type."""

    def binding(sensor: str, kind: str, topic: str, origin: str) -> Binding:
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
        return Binding(sensor, kind, topic, msgtype, codec)

    if cfg.sensors:
        return [binding(name, tb.kind, tb.topic, "configured") for name, tb in cfg.sensors.items()]
    out: list[Binding] = []
    if side is not None:
        out = [binding(s.name, s.kind, s.topic, "sidecar") for s in side.sensors.values() if s.topic]
    taken = {b.topic for b in out}
    names = {b.sensor for b in out}
    for topic, msgtype in sorted(topics.items()):
        if topic in taken or msgtype not in CODECS:
            continue
        name = topic.lstrip("/") or topic
        if name in names:
            name = topic
        out.append(Binding(name, CODECS[msgtype].kind, topic, msgtype, CODECS[msgtype]))
    return out


def read_mission(path: str | Path, config: ReaderConfig | None = None) -> BagMission:
    """Open the mission recorded in ``path`` (ROS 1 ``.bag``, ROS 2 bag directory or ``.mcap``).

    Sensors are bound to topics by ``config.sensors``; without it, by the sidecar, and every other
    topic of a supported message type becomes a sensor named after its topic ('/nav/dvl' →
    'nav/dvl'). Extrinsics T_BS: the configuration's, else the sidecar's (by sensor name, then by
    topic), else identity. Raises MissionError (one line) for everything cheap to check up front.
    """
    cfg = config or ReaderConfig()
    path = Path(path)
    side = sidecar.load(sidecar.sidecar_path(path)) if path.exists() else None
    with open_bag(path) as reader:
        version = 1 if not reader.is2 else 2
        topics = {
            name: (normalize_msgtype(info.msgtype) if info.msgtype else None) for name, info in reader.topics.items()
        }
        counts = {name: int(info.msgcount) for name, info in reader.topics.items()}
    bindings = _bind(path, topics, cfg, side)

    side_by_name = side.sensors if side else {}
    side_by_topic = {s.topic: s for s in side_by_name.values() if s.topic}
    sensors = {}
    for b in bindings:
        tb = cfg.sensors.get(b.sensor)
        if tb is not None and tb.T_BS is not None:
            T = np.asarray(tb.T_BS, dtype=float)
            if T.shape != (4, 4):
                raise MissionError(f"configuration: reader.sensors.{b.sensor}.T_BS: expected 4×4, got {T.shape}")
        elif b.sensor in side_by_name:
            T = side_by_name[b.sensor].T_BS
        elif b.topic in side_by_topic:
            T = side_by_topic[b.topic].T_BS
        else:
            T = np.eye(4)
        sensors[b.sensor] = SensorInfo(name=b.sensor, kind=b.kind, topic=b.topic, msgtype=b.msgtype, T_BS=T)
    name = side.name if side else (path.stem if path.is_file() else path.name)
    meta = MissionMetadata(
        name=name,
        sensors=sensors,
        ground_truth=side.ground_truth if side else None,
        extras=dict(side.extras) if side else {},
    )
    return BagMission(meta, path, bindings, cfg, version, counts)
