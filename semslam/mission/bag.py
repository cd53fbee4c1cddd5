"""ROS bag I/O of missions: the public entry points.

* ``read_mission(path, config=None) -> Mission`` — ROS 1 ``.bag``, ROS 2 bag directory (sqlite3 or
  mcap storage) or ``.mcap`` file, read with rosbags ``AnyReader``; see ``bag_reader``.
* ``write_mission(mission, path, *, config=None, overwrite=False) -> Path`` — ``.bag`` → ROS 1,
  ``.mcap`` → ROS 2 mcap file, otherwise a ROS 2 sqlite3 directory; see ``bag_writer``.

Message mapping and its conventions: ``conversions``; the sidecar JSON (extrinsics, ground truth,
extras) and where it lives: ``sidecar``; the shipped COLA2 message definitions: ``typestore``.
"""

from semslam.mission.bag_reader import BagMission, read_mission
from semslam.mission.bag_writer import write_mission
from semslam.mission.sidecar import sidecar_path

__all__ = ["BagMission", "read_mission", "sidecar_path", "write_mission"]
