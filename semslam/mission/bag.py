"""ROS bag I/O of missions: the public entry points.

* ``read_mission(path, config=None) -> BagMission`` (a ``Mission``) — a ROS 1 ``.bag``, a ROS 2
  bag directory (sqlite3 or mcap storage), or a ``.mcap`` / ``.db3`` file, read with rosbags
  ``AnyReader``; measurements stream in header-stamp order; NaN/inf measurements are dropped and
  counted in ``mission.dropped``; every user error is a one-line ``MissionError``. See
  ``bag_reader``.
* ``write_mission(mission, path, *, config=None, overwrite=False) -> Path`` — ``*.bag`` → ROS 1,
  ``*.mcap`` → a ROS 2 mcap file, anything else → a ROS 2 sqlite3 bag directory; written under a
  temporary name and renamed at the end. See ``bag_writer``.

The sidecar JSON (extrinsics T_BS, ground-truth landmarks, extras such as the simulator's noise)
lives next to a file bag as ``<file name>.semslam.json`` and inside a ROS 2 bag directory as
``semslam.json`` (``sidecar``). Message ↔ measurement mapping and its conventions (DVL validity,
REP 145 / REP 117): ``conversions``. Shipped COLA2 message definitions: ``typestore``.
"""

from semslam.mission.bag_reader import BagMission, read_mission
from semslam.mission.bag_writer import write_mission
from semslam.mission.sidecar import sidecar_path

__all__ = ["BagMission", "read_mission", "sidecar_path", "write_mission"]
