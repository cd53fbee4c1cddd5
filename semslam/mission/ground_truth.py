"""Ground-truth landmarks of a (simulated) mission: objects, pipes and CAD structures in {W}.

Stored in the mission's sidecar JSON next to the bag; real missions usually have none.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np


def homogeneous(position, orientation_xyzw) -> np.ndarray:
    """The 4×4 transform of a position and a unit quaternion (x, y, z, w)."""
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(orientation_xyzw).as_matrix()
    T[:3, 3] = position
    return T


@dataclass(frozen=True)
class GtObject:
    """An object (valve, elbow, ...) with its class, pose T_W,object and the pipes attached to it."""

    id: int
    cls: str
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)  # (x, y, z, w)
    pipes: tuple[int, ...] = ()
    model: str | None = None  # CAD model name in the model library, when known


@dataclass(frozen=True)
class GtPipe:
    """A straight pipe from ``p`` to ``q`` (its axis) with radius in metres."""

    id: int
    p: tuple[float, float, float]
    q: tuple[float, float, float]
    radius: float


@dataclass(frozen=True)
class GtStructure:
    """A CAD-known structure (sonar path) with its pose T_W,model."""

    id: int
    model: str
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    def matrix(self) -> np.ndarray:
        """T_W,model as a 4×4 homogeneous matrix."""
        return homogeneous(self.position, self.orientation)


@dataclass(frozen=True)
class GroundTruthMap:
    """All ground-truth landmarks; ``seen`` lists the ids that the sensors actually saw (hit by a ray)."""

    classes: tuple[str, ...] = ()
    objects: tuple[GtObject, ...] = ()
    pipes: tuple[GtPipe, ...] = ()
    structures: tuple[GtStructure, ...] = ()
    seen_objects: tuple[int, ...] | None = None
    seen_pipes: tuple[int, ...] | None = None
    seen_structures: tuple[int, ...] | None = None
    extras: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> GroundTruthMap:
        def tup(x):
            return None if x is None else tuple(x)

        return cls(
            classes=tuple(d.get("classes", ())),
            objects=tuple(
                GtObject(
                    id=int(o["id"]),
                    cls=o["cls"],
                    position=tuple(map(float, o["position"])),
                    orientation=tuple(map(float, o.get("orientation", (0, 0, 0, 1)))),
                    pipes=tuple(int(p) for p in o.get("pipes", ())),
                    model=o.get("model"),
                )
                for o in d.get("objects", ())
            ),
            pipes=tuple(
                GtPipe(int(p["id"]), tuple(map(float, p["p"])), tuple(map(float, p["q"])), float(p["radius"]))
                for p in d.get("pipes", ())
            ),
            structures=tuple(
                GtStructure(
                    int(s["id"]),
                    s["model"],
                    tuple(map(float, s["position"])),
                    tuple(map(float, s.get("orientation", (0, 0, 0, 1)))),
                )
                for s in d.get("structures", ())
            ),
            seen_objects=tup(d.get("seen_objects")),
            seen_pipes=tup(d.get("seen_pipes")),
            seen_structures=tup(d.get("seen_structures")),
            extras=dict(d.get("extras", {})),
        )

    def object_positions(self) -> np.ndarray:
        return np.array([o.position for o in self.objects], dtype=float).reshape(-1, 3)
