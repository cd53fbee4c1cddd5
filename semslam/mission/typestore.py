"""rosbags type stores with the message definitions semslam ships (``msgs/``): the DVLs of COLA2
(``cola2_msgs/DVL``), Water Linked (``dvl_msgs/DVL`` of the ROS 2 driver,
``waterlinked_a50_ros_driver/DVL`` of the ROS 1 one) and UUV Simulator
(``uuv_sensor_ros_plugins_msgs/DVL``), and gps_umd's ``gps_msgs/GPSFix``.

A ROS 1 bag embeds its message definitions, a ROS 2 bag recorded by Iron or later usually does
too, but a Humble bag does not: for those, the reader falls back on these stores, so such a bag
reads without ROS or the vehicle's packages installed. A bag's own definition always wins.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

MSG_DIR = Path(__file__).parent / "msgs"


def shipped_types() -> dict:
    """Every ``msgs/<package>/msg/<Name>.msg`` shipped with semslam, as a rosbags types dict."""
    types: dict = {}
    for path in sorted(MSG_DIR.glob("*/msg/*.msg")):
        package = path.parent.parent.name
        types.update(get_types_from_msg(path.read_text(), f"{package}/msg/{path.stem}"))
    return types


@cache
def typestore(ros_version: int) -> Typestore:
    """ROS 1 (Noetic) or ROS 2 (Humble) standard types plus the shipped definitions.

    Cached: build once, share (rosbags type stores are not mutated after this).
    """
    store = get_typestore(Stores.ROS1_NOETIC if ros_version == 1 else Stores.ROS2_HUMBLE)
    store.register(shipped_types())
    return store


def add_missing_types(target: Typestore, ros_version: int, msgtypes) -> None:
    """Register into ``target`` (a bag's own store) those of ``msgtypes`` it lacks, from ours.

    A bag may embed definitions for some connections only; the others then deserialize with ours.
    Only the needed types (and what they contain) are registered: building a type is not free.
    """
    ours = typestore(ros_version)
    missing: dict = {}
    todo = [t for t in msgtypes if t not in target.fielddefs and t in ours.fielddefs]
    while todo:
        name = todo.pop()
        if name in missing or name in target.fielddefs:
            continue
        missing[name] = ours.fielddefs[name]
        todo.extend(_contained(missing[name]))
    if missing:
        target.register(missing)


def _contained(fielddef) -> list[str]:
    """Names of the message types used by the fields of one rosbags field definition."""
    out = []

    def walk(desc):
        kind, rest = desc
        if kind.name == "NAME":
            out.append(rest)
        elif kind.name in ("ARRAY", "SEQUENCE"):
            walk(rest[0])

    for _, desc in fielddef[1]:
        walk(desc)
    return out
