"""Standard ROS 2 messages (rosbags' Humble type store) built from semslam's numpy data.

Only what the replay (:mod:`semslam.eval.replay`) writes: headers, poses, transforms, paths,
markers and point clouds. Stamps are integer nanoseconds, as everywhere in semslam.
"""

from __future__ import annotations

import numpy as np

from semslam.mission.typestore import typestore

STORE = typestore(2)
_T = STORE.types
Marker = _T["visualization_msgs/msg/Marker"]
_Time = _T["builtin_interfaces/msg/Time"]
_Duration = _T["builtin_interfaces/msg/Duration"]
_Header = _T["std_msgs/msg/Header"]
_Point = _T["geometry_msgs/msg/Point"]
_Quaternion = _T["geometry_msgs/msg/Quaternion"]
_Vector3 = _T["geometry_msgs/msg/Vector3"]
_Pose = _T["geometry_msgs/msg/Pose"]
_ColorRGBA = _T["std_msgs/msg/ColorRGBA"]
_PointField = _T["sensor_msgs/msg/PointField"]

POSE_COV = "geometry_msgs/msg/PoseWithCovarianceStamped"
POSE = "geometry_msgs/msg/PoseStamped"
PATH = "nav_msgs/msg/Path"
TF = "tf2_msgs/msg/TFMessage"
MARKERS = "visualization_msgs/msg/MarkerArray"
CLOUD = "sensor_msgs/msg/PointCloud2"


def serialize(msg) -> bytes:
    return STORE.serialize_cdr(msg, msg.__msgtype__)


def header(stamp: int, frame: str):
    sec, nsec = divmod(int(stamp), 1_000_000_000)
    return _Header(stamp=_Time(sec=sec, nanosec=nsec), frame_id=frame)


def pose(position, quat_xyzw):
    x, y, z = (float(v) for v in position)
    qx, qy, qz, qw = (float(v) for v in quat_xyzw)
    return _Pose(position=_Point(x=x, y=y, z=z), orientation=_Quaternion(x=qx, y=qy, z=qz, w=qw))


def pose_stamped(stamp: int, frame: str, position, quat_xyzw):
    return _T[POSE](header=header(stamp, frame), pose=pose(position, quat_xyzw))


def pose_with_covariance(stamp: int, frame: str, position, quat_xyzw, position_cov=None):
    """The position block of the 6×6 covariance (x, y, z, then rotations) is ``position_cov``;
    semslam's trajectories carry no attitude covariance, so the rotation block is zero."""
    cov = np.zeros((6, 6))
    if position_cov is not None:
        cov[:3, :3] = position_cov
    inner = _T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(position, quat_xyzw), covariance=cov.reshape(36))
    return _T[POSE_COV](header=header(stamp, frame), pose=inner)


def path(stamp: int, frame: str, stamps, positions, quats):
    poses = [pose_stamped(s, frame, p, q) for s, p, q in zip(stamps, positions, quats)]
    return _T[PATH](header=header(stamp, frame), poses=poses)


def transform(stamp: int, parent: str, child: str, translation, quat_xyzw):
    x, y, z = (float(v) for v in translation)
    qx, qy, qz, qw = (float(v) for v in quat_xyzw)
    tf = _T["geometry_msgs/msg/Transform"](
        translation=_Vector3(x=x, y=y, z=z), rotation=_Quaternion(x=qx, y=qy, z=qz, w=qw)
    )
    return _T["geometry_msgs/msg/TransformStamped"](header=header(stamp, parent), child_frame_id=child, transform=tf)


def tf_message(transforms: list):
    return _T[TF](transforms=transforms)


def color(rgb, alpha: float = 1.0):
    r, g, b = (float(v) for v in rgb)
    return _ColorRGBA(r=r, g=g, b=b, a=float(alpha))


def marker(
    stamp: int,
    frame: str,
    ns: str,
    id: int,
    type: int,
    position=(0.0, 0.0, 0.0),
    quat_xyzw=(0.0, 0.0, 0.0, 1.0),
    scale=(1.0, 1.0, 1.0),
    rgba=(1.0, 1.0, 1.0, 1.0),
    points: np.ndarray | None = None,
    text: str = "",
    action: int = Marker.ADD,
):
    """One marker, forever (lifetime 0) until a later DELETE or DELETEALL."""
    sx, sy, sz = (float(v) for v in scale)
    pts = [] if points is None else [_Point(x=float(a), y=float(b), z=float(c)) for a, b, c in points]
    return Marker(
        header=header(stamp, frame),
        ns=ns,
        id=int(id),
        type=int(type),
        action=int(action),
        pose=pose(position, quat_xyzw),
        scale=_Vector3(x=sx, y=sy, z=sz),
        color=color(rgba[:3], rgba[3]),
        lifetime=_Duration(sec=0, nanosec=0),
        frame_locked=False,
        points=pts,
        colors=[],
        texture_resource="",
        texture=_T["sensor_msgs/msg/CompressedImage"](header=header(0, ""), format="", data=np.zeros(0, np.uint8)),
        uv_coordinates=[],
        text=text,
        mesh_resource="",
        mesh_file=_T["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
        mesh_use_embedded_materials=False,
    )


def delete_all(stamp: int, frame: str):
    """The marker that clears what an earlier MarkerArray on the topic drew."""
    return marker(stamp, frame, "", 0, Marker.SPHERE, action=Marker.DELETEALL)


def marker_array(markers: list):
    return _T[MARKERS](markers=markers)


# PointField datatypes (sensor_msgs/PointField)
_UINT8, _FLOAT32 = 2, 7
# x, y, z and rgb (RViz's packed float) as float32, then two uint8 labels; padded to 4-byte alignment.
CLOUD_DTYPE = np.dtype(
    {
        "names": ["x", "y", "z", "rgb", "segment", "class"],
        "formats": ["<f4", "<f4", "<f4", "<u4", "u1", "u1"],
        "offsets": [0, 4, 8, 12, 16, 17],
        "itemsize": 20,
    }
)


def point_cloud(stamp: int, frame: str, xyz: np.ndarray, rgb: np.ndarray, segment: np.ndarray, cls: np.ndarray):
    """An unordered cloud: ``xyz`` (N, 3), ``rgb`` (N, 3) uint8, ``segment`` and ``cls`` (N,) uint8."""
    n = len(xyz)
    data = np.zeros(n, CLOUD_DTYPE)
    data["x"], data["y"], data["z"] = (np.asarray(xyz, np.float32)[:, k] for k in range(3))
    rgb = np.asarray(rgb, np.uint32).reshape(n, 3)
    data["rgb"] = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
    data["segment"], data["class"] = segment, cls
    fields = [
        _PointField(name=name, offset=CLOUD_DTYPE.fields[name][1], datatype=dt, count=1)
        for name, dt in (("x", _FLOAT32), ("y", _FLOAT32), ("z", _FLOAT32), ("rgb", _FLOAT32))
    ] + [
        _PointField(name=name, offset=CLOUD_DTYPE.fields[name][1], datatype=_UINT8, count=1)
        for name in ("segment", "class")
    ]
    return _T[CLOUD](
        header=header(stamp, frame),
        height=1,
        width=n,
        fields=fields,
        is_bigendian=False,
        point_step=CLOUD_DTYPE.itemsize,
        row_step=CLOUD_DTYPE.itemsize * n,
        data=np.frombuffer(data.tobytes(), np.uint8),
        is_dense=True,
    )


def cloud_points(msg) -> np.ndarray:
    """A cloud written by :func:`point_cloud` back as a structured array (fields x, y, z, rgb, segment, class)."""
    return np.frombuffer(np.asarray(msg.data, np.uint8).tobytes(), CLOUD_DTYPE, count=msg.width)
