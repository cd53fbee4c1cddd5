"""Reading a ROS 1 ``.bag``, a ROS 2 bag directory (sqlite3 or mcap storage) or a ``.mcap`` file.

What is cheap is checked when the mission is opened (the path exists and is a bag, the bag opens
and its index reads, every configured topic exists with a supported message type, the sidecar is
valid); then the first messages of each sensor topic are looked at (``probe``) to choose the
topics (``binding``) and their clock (``stamps``), and the surface pressure and GPS datum are
resolved (``surface``). What needs the messages (corrupt chunks, malformed or non-finite messages,
stamps going backwards) is found while streaming. Every such problem is a ``MissionError`` with
one line naming the file, topic and stamp or field. Only the bound topics are read and checked:
a topic nobody needs never stops a read.

Streaming: messages come from the bag in recording-time order; measurements are released in
stamp order through a reorder buffer: a measurement is released once a message stamped
``ReaderConfig.reorder_window_s`` later has arrived, so sensors with different latencies still
interleave correctly (the window is in mission-clock time, so it does not matter whether the
recording clock is the same as the stamps' — wall time vs simulated time).
"""

from __future__ import annotations

import dataclasses
import heapq
import logging
from collections import Counter, defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from semslam.errors import MissionError, one_line
from semslam.mission import sidecar
from semslam.mission.binding import BindingPlan, plan_bindings
from semslam.mission.clock_guard import ClockProblem, Segment, StampGuard, TopicClock, regular_period
from semslam.mission.codec_base import (
    DecodeContext,
    MalformedMessage,
    Unusable,
    normalize_msgtype,
    short_msgtype,
    stamp_ns,
)
from semslam.mission.config import ReaderConfig
from semslam.mission.conversions import CODECS, ROS1_FAST, Ros1Fast
from semslam.mission.measurements import Depth, Measurement, PointCloud
from semslam.mission.mission import Mission, MissionMetadata, SensorInfo
from semslam.mission.plausible import implausible
from semslam.mission.probe import LARGE, probe_topics
from semslam.mission.stamps import ClockOffset, StampChoice, choose_stamp, estimate_offset
from semslam.mission.surface import Resolved, resolve_atmosphere, resolve_datum
from semslam.mission.typestore import add_missing_types, typestore

log = logging.getLogger("semslam.mission")


@dataclasses.dataclass(frozen=True)
class ReadPlan:
    """How the mission is read, as decided when it was opened (``semslam info`` reports it)."""

    binding: BindingPlan
    stamps: dict[str, StampChoice]  # sensor → its stamp source
    clock: ClockOffset
    atmosphere: Resolved  # the surface pressure (Pa) depth is computed with
    datum: Resolved  # the GPS fixes' origin (Geodetic | None)
    clocks: dict[str, TopicClock]  # topic → what the stamp guard knows of it
    extrinsics: dict[str, str]  # sensor → where its T_BS came from: reader.sensors | sidecar | assumed


class BagMission(Mission):
    """A Mission streamed from a bag. Adds what ``semslam info`` reports beyond ``Mission``.

    ``dropped`` (sensor → count) and ``dropped_fields`` (sensor → field or reason → count) are those
    of the last complete pass over the bag, as are ``first_dropped`` (sensor → stamp reason → first
    stamp), ``notes`` (sensor → assumption → count, e.g. a covariance a message left unknown),
    ``warnings`` (sensor → what looks wrong → count, e.g. a point cloud in millimetres),
    ``clock_problems`` (clock resets, interleaved stretches, repeated stamps: ``clock_guard``) and
    ``segments`` (the parts between clock resets); ``message_counts`` (topic → count) come from the
    bag's index. ``survey``: clock problems are recorded, not raised (``semslam info``).
    """

    def __init__(
        self,
        metadata: MissionMetadata,
        path: Path,
        plan: ReadPlan,
        config: ReaderConfig,
        ros_version: int,
        message_counts: dict[str, int],
        survey: bool = False,
    ):
        super().__init__(metadata, self._stream)
        self.path = path
        self.plan = plan
        self.bindings = plan.binding.bindings
        self.config = config
        self.ros_version = ros_version
        self.message_counts = message_counts
        self.survey = survey
        self.dropped_fields: dict[str, Counter[str]] = {}
        self.first_dropped: dict[str, dict[str, int]] = {}
        self.clock_problems: list[ClockProblem] = []
        self.segments: list[Segment] = []
        self.recording_start: int | None = None  # the first stamp: mission time 0 of clock_problems
        self.notes: dict[str, Counter[str]] = {}
        self.warnings: dict[str, Counter[str]] = {}

    @property
    def message_count(self) -> int:
        """Messages on the bound topics (from the index): the length of a full pass, for progress bars."""
        return sum(self.message_counts.get(b.topic, 0) for b in self.bindings)

    def only(self, sensors) -> BagMission:
        """The same bag reading only the topics of ``sensors`` (a cheap pass, e.g. over the GPS fixes
        and the depth that decides which fixes are kept)."""
        keep = set(sensors)
        binding = dataclasses.replace(self.plan.binding, bindings=[b for b in self.bindings if b.sensor in keep])
        plan = dataclasses.replace(self.plan, binding=binding)
        return BagMission(self.metadata, self.path, plan, self.config, self.ros_version, self.message_counts)

    def _stream(self) -> Iterator[Measurement]:
        cfg = self.config
        window = int(cfg.reorder_window_s * 1e9)
        by_topic = {b.topic: b for b in self.bindings}
        depth_topic = next((b.topic for b in self.bindings if b.kind == "depth"), None)
        # What the stream does with a topic's measurements beyond the common checks.
        role = {
            b.topic: "gps" if b.kind == "gps" else "cloud" if b.kind in ("laser", "sonar") else None
            for b in self.bindings
        }
        if depth_topic is not None:
            role[depth_topic] = "depth"
        ctx = DecodeContext(cfg, float(self.plan.atmosphere.value), self.metadata.datum)
        clouds = _CloudCheck(cfg.cloud_range_m)
        dropped: Counter[str] = Counter()
        fields: dict[str, Counter[str]] = defaultdict(Counter)
        guard = StampGuard(
            self.path, self.plan.clocks, self.plan.clock.offset_ns, cfg, self.ros_version, dropped, fields, self.survey
        )
        last_depth: float | None = None
        released = -(2**63)
        newest = -(2**63)
        heap: list[tuple[int, int, Measurement]] = []
        seq = 0
        with open_bag(self.path) as reader:
            conns = [c for c in reader.connections if c.topic in by_topic]
            fast = _fast_paths(reader, conns, self.ros_version)
            where = {t: f"{self.path}: topic {t}" for t in by_topic}  # every error's prefix, per topic
            messages = reader.messages(connections=conns)
            while not guard.done:
                try:
                    item = next(messages, None)
                except Exception as exc:  # a damaged chunk / page / record: any rosbags or storage error
                    raise MissionError(f"{self.path}: corrupt or truncated bag ({one_line(exc)})") from None
                if item is None:
                    break
                conn, t_bag, raw = item
                topic = conn.topic
                f = fast.get(topic)
                parsed = f.parse(raw) if f is not None else None
                if parsed is None:
                    try:
                        parsed = reader.deserialize(raw, conn.msgtype)
                    except Exception as exc:
                        raise MissionError(
                            f"{where[topic]}: message at t={t_bag * 1e-9:.6f} s cannot be decoded as "
                            f"{short_msgtype(conn.msgtype)} ({one_line(exc)})"
                        ) from None
                    header_stamp = stamp_ns(parsed.header)
                    admitted = guard.admit(topic, t_bag, header_stamp, raw, (header_stamp, None, parsed))
                else:
                    header_stamp = parsed[0]
                    admitted = guard.admit(topic, t_bag, header_stamp, raw, (header_stamp, parsed[1], None))
                b = by_topic[topic]
                for (header_stamp, values, msg), stamp in admitted:
                    if ctx.pending:  # notes of a message dropped after decoding
                        ctx.pending.clear()
                    try:
                        if values is None:
                            m = b.codec.decode(msg, b.sensor, ctx)
                        else:
                            m = f.build(header_stamp, values, b.sensor, ctx)
                    except MalformedMessage as exc:
                        raise MissionError(f"{where[topic]}: {exc} (message at t={stamp * 1e-9:.6f} s)") from None
                    except Unusable as exc:  # e.g. an Imu without orientation: no AHRS reading in it
                        dropped[b.sensor] += 1
                        fields[b.sensor][exc.field] += 1
                        continue
                    if m.stamp != stamp:
                        m = dataclasses.replace(m, stamp=stamp)
                    bad = m.nonfinite_field()
                    wild = implausible(m, cfg.plausible) if bad is None else None
                    if bad is not None or wild is not None:
                        if cfg.on_nonfinite == "error":
                            why = f"field {bad} is not finite or not a covariance" if wild is None else wild
                            raise MissionError(f"{where[topic]}: {why} (message at t={stamp * 1e-9:.6f} s)")
                        dropped[b.sensor] += 1
                        fields[b.sensor][bad or wild] += 1
                        continue
                    r = role[topic]
                    if r is None:
                        pass
                    elif r == "depth" and isinstance(m, Depth):
                        last_depth = m.depth
                    elif r == "gps" and last_depth is not None and last_depth > cfg.gps_max_depth_m:
                        dropped[b.sensor] += 1
                        fields[b.sensor][f"taken below {cfg.gps_max_depth_m:g} m depth"] += 1
                        continue
                    elif r == "cloud" and isinstance(m, PointCloud):
                        clouds.check(m, where[topic])
                    if stamp < released:
                        raise MissionError(
                            f"{where[topic]}: message stamped {stamp * 1e-9:.6f} s arrived after messages stamped "
                            f"more than reorder_window_s={cfg.reorder_window_s} s later (raise reorder_window_s)"
                        )
                    if ctx.pending:
                        ctx.commit()
                    heapq.heappush(heap, (stamp, seq, m))
                    seq += 1
                    newest = max(newest, stamp)
                    horizon = newest - window
                    while heap and heap[0][0] <= horizon:
                        released, _, out = heapq.heappop(heap)
                        yield out
            guard.finish()
            while heap:
                yield heapq.heappop(heap)[2]
        self.dropped.clear()
        self.dropped.update(dropped)
        self.dropped_fields = dict(fields)
        self.first_dropped = guard.first_drop
        self.clock_problems = guard.problems
        self.segments = guard.segments
        self.recording_start = guard.start
        self.notes = ctx.notes
        self.warnings = clouds.found
        if self.metadata.datum is None and ctx.datum is not None:
            self.metadata.datum = ctx.datum


class _CloudCheck:
    """Warns (once per sensor on the log, every time in ``found``) about point clouds whose scale
    does not fit a sensor: the median distance of their points from the sensor outside
    ``reader.cloud_range_m`` (a cloud in millimetres, a cloud in a world frame far from the sensor)."""

    SAMPLE = 1000

    def __init__(self, bounds: tuple[float, float]):
        self.lo, self.hi = bounds
        self.found: dict[str, Counter[str]] = {}

    def check(self, m: PointCloud, where: str) -> None:
        n = len(m.points)
        if n == 0:
            return
        r = float(np.median(np.linalg.norm(m.points[:: max(1, n // self.SAMPLE)], axis=1)))
        if self.lo <= r <= self.hi:
            return
        guess = "millimetres? a world-frame cloud?" if r > self.hi else "kilometres?"
        bound = f"beyond {self.hi:g} m" if r > self.hi else f"below {self.lo:g} m"
        seen = self.found.setdefault(m.sensor, Counter())
        if not seen:
            log.warning(
                "%s: point cloud at t=%.6f s: median point distance %.4g m from the sensor, outside "
                "reader.cloud_range_m [%g, %g] (%s); warned once per sensor, counted by semslam info",
                where,
                m.stamp * 1e-9,
                r,
                self.lo,
                self.hi,
                guess,
            )
        seen[f"median point distance {bound} from the sensor ({guess})"] += 1


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
        raise MissionError(f"{path}: cannot open bag, corrupt or truncated? ({one_line(exc)})") from None
    try:
        yield reader
    finally:
        try:
            reader.close()
        except Exception:  # closing a damaged bag must not hide the real error
            pass


def read_mission(path: str | Path, config: ReaderConfig | None = None, survey: bool = False) -> BagMission:
    """Open the mission recorded in ``path`` (ROS 1 ``.bag``, ROS 2 bag directory or ``.mcap``).

    Sensors are bound to topics by ``config.sensors``; without it, by the sidecar, and one topic
    per further sensor kind by the rule of ``semslam.mission.binding``. Extrinsics T_BS: the
    configuration's, else the sidecar's (by sensor name, then by topic), else identity (assumed:
    ``semslam.mission.check`` warns). Raises MissionError (one line) for everything cheap to check
    up front. ``survey`` (``semslam info``): clock problems found while streaming are recorded in
    ``clock_problems``, not raised.
    """
    cfg = config or ReaderConfig()
    path = Path(path)
    side = sidecar.load(sidecar.sidecar_path(path)) if path.exists() else None
    side_meta = side.metadata if side else None
    with open_bag(path) as reader:
        version = 1 if not reader.is2 else 2
        topics = {
            name: (normalize_msgtype(info.msgtype) if info.msgtype else None) for name, info in reader.topics.items()
        }
        counts = {name: int(info.msgcount) for name, info in reader.topics.items()}
        known = {normalize_msgtype(t) for t in reader.typestore.fielddefs}
        small = {t: m for t, m in topics.items() if m in CODECS and m not in LARGE}
        probes = probe_topics(reader, small, version)
        binding = plan_bindings(path, topics, counts, known, cfg, side_meta, probes)
        scans = {b.topic: b.msgtype for b in binding.bindings if b.msgtype in LARGE}
        probes.update(probe_topics(reader, scans, version))  # their stamps, only for the scans read
        clock, foreign = estimate_offset(probes)
        stamps = {
            b.sensor: choose_stamp(b.stamp or cfg.stamp, probes.get(b.topic), foreign.get(b.topic))
            for b in binding.bindings
        }
        depth_topic = next(
            (b.topic for b in binding.bindings if b.kind == "depth" and b.msgtype == "sensor_msgs/msg/FluidPressure"),
            None,
        )
        gps_topic = next((b.topic for b in binding.bindings if b.kind == "gps"), None)
        atmosphere = resolve_atmosphere(
            reader, cfg, side.atmospheric_pressure_pa if side else None, side is not None, depth_topic, gps_topic
        )
        datum = resolve_datum(reader, cfg, side_meta.datum if side_meta else None, gps_topic)

    side_by_name = side_meta.sensors if side_meta else {}
    side_by_topic = {s.topic: s for s in side_by_name.values() if s.topic}
    sensors = {}
    extrinsics = {}
    for b in binding.bindings:
        tb = cfg.sensors.get(b.sensor)
        if tb is not None and tb.T_BS is not None:
            T = np.asarray(tb.T_BS, dtype=float)
            if T.shape != (4, 4):
                raise MissionError(f"configuration: reader.sensors.{b.sensor}.T_BS: expected 4×4, got {T.shape}")
            extrinsics[b.sensor] = "reader.sensors"
        elif b.sensor in side_by_name or b.topic in side_by_topic:
            T = (side_by_name.get(b.sensor) or side_by_topic[b.topic]).T_BS
            extrinsics[b.sensor] = "sidecar"
        else:
            T = np.eye(4)
            extrinsics[b.sensor] = "assumed"
        sensors[b.sensor] = SensorInfo(name=b.sensor, kind=b.kind, topic=b.topic, msgtype=b.msgtype, T_BS=T)
    clocks = {
        b.topic: TopicClock(
            b.sensor,
            stamps[b.sensor].source,
            stamps[b.sensor].policy == "header",
            regular_period(probes[b.topic].header) if b.topic in probes else None,
        )
        for b in binding.bindings
    }
    name = side_meta.name if side_meta else (path.stem if path.is_file() else path.name)
    meta = MissionMetadata(
        name=name,
        sensors=sensors,
        ground_truth=side_meta.ground_truth if side_meta else None,
        extras=dict(side_meta.extras) if side_meta else {},
        datum=datum.value,
    )
    plan = ReadPlan(binding, stamps, clock, atmosphere, datum, clocks, extrinsics)
    return BagMission(meta, path, plan, cfg, version, counts, survey)
