"""Writing a Mission as an ordinary bag (ROS 1 ``.bag``, ROS 2 ``.mcap`` file or sqlite3 directory).

Message types are those of ``conversions.MSGTYPE_OF`` (DVL as ``cola2_msgs/DVL`` so that validity
and beam flags round-trip, GPS fixes as ``sensor_msgs/NavSatFix`` about the mission's datum);
recording time = header stamp. The sidecar JSON (extrinsics, ground truth, extras, the datum and
the atmospheric pressure depth was converted with) is written where ``sidecar.sidecar_path`` says. Nothing is half-written: the bag
and its sidecar are built in a hidden temporary directory beside the target and renamed into
place at the end (the bag last), and the temporary directory is removed on failure.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from semslam.errors import MissionError
from semslam.mission import sidecar
from semslam.mission.config import ReaderConfig, writing_atmosphere_pa
from semslam.mission.conversions import KIND_OF, MSGTYPE_OF, Encoder, Unencodable
from semslam.mission.mission import Mission, MissionMetadata, SensorInfo
from semslam.mission.typestore import typestore

# The message type a sensor of each kind is written with when it has no measurement to tell.
_MSGTYPE_OF_KIND = {KIND_OF[t]: MSGTYPE_OF[t] for t in MSGTYPE_OF}


def bag_format(path: Path) -> str:
    """'ros1' for ``*.bag``, 'mcap' for ``*.mcap``, otherwise 'sqlite3' (a ROS 2 bag directory)."""
    return {".bag": "ros1", ".mcap": "mcap"}.get(path.suffix, "sqlite3")


class _Sink:
    """One rosbags writer plus its connections (one per topic) and serializer."""

    def __init__(self, fmt: str, target: Path):
        self.ros_version = 1 if fmt == "ros1" else 2
        self.store = typestore(self.ros_version)
        if fmt == "ros1":
            from rosbags.rosbag1 import Writer

            self.writer = Writer(target)
            self.serialize = self.store.serialize_ros1
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer(target, version=Writer.VERSION_LATEST, storage_plugin=plugin)
            self.serialize = self.store.serialize_cdr
        self.writer.open()
        self.connections: dict[str, tuple[str, object]] = {}  # topic → (msgtype, connection)

    def connection(self, topic: str, msgtype: str, sensor: str):
        have = self.connections.get(topic)
        if have is None:
            conn = self.writer.add_connection(topic, msgtype, typestore=self.store)
            self.connections[topic] = have = (msgtype, conn)
        elif have[0] != msgtype:
            raise MissionError(f"sensor {sensor!r}: topic {topic} would carry both {have[0]} and {msgtype}")
        return have[1]

    def write(self, conn, stamp: int, msg, msgtype: str) -> None:
        self.writer.write(conn, stamp, self.serialize(msg, msgtype))


def _topic_of(name: str, info: SensorInfo | None) -> str:
    return info.topic if info is not None and info.topic else "/" + name.lstrip("/")


def write_mission(
    mission: Mission, path: str | Path, *, config: ReaderConfig | None = None, overwrite: bool = False
) -> Path:
    """Write ``mission`` to ``path`` and return the path of the bag.

    ``*.bag`` → ROS 1; ``*.mcap`` → a ROS 2 mcap file; anything else → a ROS 2 sqlite3 bag
    directory. ``config`` supplies the constants of the depth ↔ pressure conversion (use the ones
    the mission will be read with). An existing ``path`` is an error unless ``overwrite``.
    """
    cfg = config or ReaderConfig()
    path = Path(path)
    fmt = bag_format(path)
    if not path.parent.is_dir():
        raise MissionError(f"{path}: parent directory {path.parent} does not exist")
    if path.exists() and not overwrite:
        raise MissionError(f"{path}: exists already (not overwriting)")

    meta = mission.metadata
    tmpdir = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        # ROS 2 writers create a directory; an .mcap file is taken out of it afterwards.
        target = tmpdir / (path.stem if fmt == "mcap" else path.name)
        sensors = _write_messages(mission, fmt, target, cfg)
        staged = target / f"{path.stem}.mcap" if fmt == "mcap" else target
        side = MissionMetadata(
            name=meta.name, sensors=sensors, ground_truth=meta.ground_truth, extras=meta.extras, datum=meta.datum
        )
        side_text = sidecar.dumps(side, writing_atmosphere_pa(cfg))
        if fmt == "sqlite3":
            (staged / sidecar.DIR_SIDECAR).write_text(side_text)
            _replace(staged, path)
        else:
            side_tmp = tmpdir / "sidecar.json"
            side_tmp.write_text(side_text)
            os.replace(side_tmp, path.with_name(path.name + sidecar.FILE_SUFFIX))
            _replace(staged, path)
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)
    return path


def _replace(src: Path, dst: Path) -> None:
    """Rename ``src`` onto ``dst`` (same directory); an existing directory ``dst`` is swapped out."""
    if dst.is_dir() and not dst.is_symlink():
        trash = dst.with_name(f".{dst.name}.old-{os.getpid()}")
        os.replace(dst, trash)
        os.replace(src, dst)
        shutil.rmtree(trash, ignore_errors=True)
    else:
        os.replace(src, dst)


def _write_messages(mission: Mission, fmt: str, target: Path, cfg: ReaderConfig) -> dict[str, SensorInfo]:
    """Write every measurement; return the sensors as the sidecar must describe them."""
    meta = mission.metadata
    sink = _Sink(fmt, target)
    encoder = Encoder(sink.store, sink.ros_version, cfg, meta.datum)
    sensors: dict[str, SensorInfo] = {}
    topics: dict[str, str] = {}  # topic → sensor, to refuse two sensors on one topic
    try:
        for m in mission:
            info = sensors.get(m.sensor)
            if info is None:
                given = meta.sensors.get(m.sensor)
                topic = _topic_of(m.sensor, given)
                if topics.setdefault(topic, m.sensor) != m.sensor:
                    raise MissionError(f"sensors {topics[topic]!r} and {m.sensor!r} both map to topic {topic}")
                info = SensorInfo(
                    m.sensor,
                    given.kind if given is not None else KIND_OF[type(m)],
                    topic=topic,
                    msgtype=MSGTYPE_OF[type(m)],
                    T_BS=given.T_BS if given is not None else np.eye(4),
                )
                sensors[m.sensor] = info
            msgtype = MSGTYPE_OF[type(m)]
            if msgtype != info.msgtype:
                raise MissionError(f"sensor {m.sensor!r} has both {info.msgtype} and {msgtype} measurements")
            conn = sink.connection(info.topic, msgtype, m.sensor)
            try:
                msg = encoder.encode(m, m.sensor)
            except Unencodable as exc:
                raise MissionError(f"sensor {m.sensor!r} at t={m.stamp * 1e-9:.6f} s: {exc}") from None
            sink.write(conn, m.stamp, msg, msgtype)
        # Sensors without a single measurement still get their (empty) topic, so they read back.
        for name, given in meta.sensors.items():
            if name in sensors:
                continue
            topic = _topic_of(name, given)
            if topics.setdefault(topic, name) != name:
                raise MissionError(f"sensors {topics[topic]!r} and {name!r} both map to topic {topic}")
            msgtype = _MSGTYPE_OF_KIND[given.kind]
            sink.connection(topic, msgtype, name)
            sensors[name] = SensorInfo(name, given.kind, topic=topic, msgtype=msgtype, T_BS=given.T_BS)
    except BaseException:
        try:
            sink.writer.abort()  # release the file handles; the temporary directory is removed by the caller
        except Exception:
            pass
        raise
    sink.writer.close()
    return sensors
