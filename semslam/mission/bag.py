"""ROS bag I/O of missions: the public entry points.

* ``read_mission(path, config=None) -> BagMission`` (a ``Mission``) — a ROS 1 ``.bag``, a ROS 2
  bag directory (sqlite3 or mcap storage), or a ``.mcap`` / ``.db3`` file, read with rosbags
  ``AnyReader``; one topic per sensor kind unless configured (``binding``); measurements stream
  in stamp order (``stamps``: header stamps, or receive time mapped onto the header clock);
  NaN/inf and unusable messages are dropped and counted in ``mission.dropped``; stamps out of order,
  clock resets and interleaved recordings are ``clock_guard``'s; every user error is a one-line
  ``MissionError``; ``mission.plan`` says how it was read. See ``bag_reader``. Before running a
  mission, ``semslam.mission.check.check_mission`` says whether it can be (velocity and attitude
  sources, extrinsics).
* ``write_mission(mission, path, *, config=None, overwrite=False) -> Path`` — ``*.bag`` → ROS 1,
  ``*.mcap`` → a ROS 2 mcap file, anything else → a ROS 2 sqlite3 bag directory; written under a
  temporary name and renamed at the end. See ``bag_writer``.

The sidecar JSON (extrinsics T_BS, ground-truth landmarks, extras such as the simulator's noise,
the GPS datum, the surface pressure) lives next to a file bag as ``<file name>.semslam.json`` and
inside a ROS 2 bag directory as ``semslam.json`` (``sidecar``). Message ↔ measurement mapping and
its conventions (DVL validity per vendor, GPS, REP 145 / REP 117): ``conversions``. Shipped
message definitions (COLA2, Water Linked, UUV Simulator DVLs; gps_msgs): ``typestore``.
"""

from semslam.mission.bag_reader import BagMission, read_mission
from semslam.mission.bag_writer import write_mission
from semslam.mission.sidecar import sidecar_path

__all__ = ["BagMission", "read_mission", "sidecar_path", "write_mission"]
