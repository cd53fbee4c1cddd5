"""The map as ``visualization_msgs/Marker``s: estimated landmarks and the ground truth.

Objects are spheres coloured by their most probable class with a label (id, class, probability);
pipes are cylinders of their radius over their seen extent; structures (and the true objects) are
their CAD meshes from :mod:`semslam.models`; each landmark with a position covariance gets its
95 % confidence ellipsoid. Everything is in the world frame {W} (NED).
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from semslam.estimation import LandmarkEstimate
from semslam.eval import ros_messages as rm
from semslam.mission.ground_truth import GroundTruthMap, homogeneous
from semslam.models.cad import CLASS_COLORS, CLASSES

M = rm.Marker
OBJECT_DIAMETER_M = 0.08
LABEL_HEIGHT_M = 0.05
ELLIPSOID_SCALE = float(np.sqrt(chi2.ppf(0.95, 3)))  # 95 % of a 3-D Gaussian lies within this many σ
MESH_TRIANGLES = 300  # CAD meshes are simplified to about this many triangles for the viewer
UNKNOWN_RGB = (0.6, 0.6, 0.6)
PIPE_RGB = (0.25, 0.45, 0.85)
STRUCTURE_RGB = (0.9, 0.6, 0.15)
UP = np.array([0.0, 0.0, -1.0])  # NED


def class_rgb(cls: str | None) -> tuple[float, float, float]:
    return CLASS_COLORS.get(cls, UNKNOWN_RGB) if cls else UNKNOWN_RGB


def class_index(cls: str | None) -> int:
    """Index of ``cls`` among the built-in classes; 255 for none or another."""
    return CLASSES.index(cls) if cls in CLASSES else 255


def map_class(posterior) -> tuple[str | None, float]:
    """The most probable class and its probability (None, 0 without a posterior)."""
    if not posterior:
        return None, 0.0
    cls = max(posterior, key=posterior.get)
    return cls, float(posterior[cls])


def _quat_z_to(direction: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w) of the shortest rotation taking +z onto ``direction`` (a marker
    cylinder's axis): half-way between the two, (z × d, 1 + z·d) normalised."""
    d = direction / np.linalg.norm(direction)
    if d[2] < -1 + 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    q = np.array([-d[1], d[0], 0.0, 1.0 + d[2]])
    return q / np.linalg.norm(q)


def ellipsoid(stamp: int, frame: str, ns: str, id: int, centre, cov: np.ndarray, rgb) -> object | None:
    """The 95 % confidence ellipsoid of a 3×3 position covariance; None if it is not one."""
    cov = np.asarray(cov, float)
    if cov.shape != (3, 3) or not np.all(np.isfinite(cov)):
        return None
    w, V = np.linalg.eigh(0.5 * (cov + cov.T))
    if w[0] <= 0:
        return None
    if np.linalg.det(V) < 0:
        V[:, 0] = -V[:, 0]
    diameters = 2 * ELLIPSOID_SCALE * np.sqrt(w)
    quat = Rotation.from_matrix(V).as_quat()
    return rm.marker(stamp, frame, ns, id, M.SPHERE, centre, quat, diameters, (*rgb, 0.35))


@functools.cache
def _mesh_triangles(kind: str, name: str) -> np.ndarray | None:
    """(3·T, 3) vertices of a library mesh (``kind`` "structure" or "object"), simplified for the
    viewer; None for a model the library does not know."""
    from semslam.models.cad import library
    from semslam.models.structures import structure_library

    lib = structure_library() if kind == "structure" else library()
    model = lib.get(name)
    if model is None:
        return None
    mesh = model.mesh
    if len(mesh.triangles) > MESH_TRIANGLES:
        mesh = mesh.simplify_quadric_decimation(MESH_TRIANGLES)
    return np.asarray(mesh.vertices)[np.asarray(mesh.triangles)].reshape(-1, 3)


def _mesh_marker(stamp, frame, ns, id, kind, name, T: np.ndarray, rgba):
    tris = _mesh_triangles(kind, name) if name else None
    position, quat = T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_quat()
    if tris is None:  # a model the library lacks: a cube where it is
        return rm.marker(stamp, frame, ns, id, M.CUBE, position, quat, (0.3, 0.3, 0.3), rgba)
    return rm.marker(stamp, frame, ns, id, M.TRIANGLE_LIST, position, quat, (1, 1, 1), rgba, points=tris)


def _pipe_marker(stamp, frame, ns, id, p, q, radius, rgba):
    p, q = np.asarray(p, float), np.asarray(q, float)
    axis = q - p
    length = float(np.linalg.norm(axis))
    if length < 1e-6:
        return None
    return rm.marker(
        stamp, frame, ns, id, M.CYLINDER, (p + q) / 2, _quat_z_to(axis), (2 * radius, 2 * radius, length), rgba
    )


def landmark_markers(stamp: int, frame: str, landmarks: list[LandmarkEstimate], pipe_radius: float) -> list:
    """A map update: DELETEALL, then every landmark (namespaces objects, labels, pipes, structures,
    ellipsoids; marker id = landmark id)."""
    out = [rm.delete_all(stamp, frame)]
    for lm in landmarks:
        if lm.kind == "object" and lm.position is not None:
            cls, prob = map_class(lm.class_posterior)
            rgb = class_rgb(cls)
            d = OBJECT_DIAMETER_M
            out.append(
                rm.marker(stamp, frame, "objects", lm.id, M.SPHERE, lm.position, scale=(d, d, d), rgba=(*rgb, 1))
            )
            text = f"{lm.id} {cls} {prob:.2f}" if cls else f"{lm.id}"
            label_at = np.asarray(lm.position) + UP * (d + LABEL_HEIGHT_M)
            out.append(
                rm.marker(
                    stamp, frame, "labels", lm.id, M.TEXT_VIEW_FACING, label_at, scale=(0, 0, LABEL_HEIGHT_M), text=text
                )
            )
            centre, cov = lm.position, lm.covariance
        elif lm.kind == "pipe" and lm.p is not None:
            m = _pipe_marker(stamp, frame, "pipes", lm.id, lm.p, lm.q, pipe_radius, (*PIPE_RGB, 1))
            if m is not None:
                out.append(m)
            continue  # a pipe's covariance is over the estimator's own line parameters, not a position
        elif lm.kind == "structure" and lm.pose is not None:
            T = np.asarray(lm.pose, float)
            out.append(_mesh_marker(stamp, frame, "structures", lm.id, "structure", lm.model, T, (*STRUCTURE_RGB, 1)))
            centre = T[:3, 3]
            cov = None if lm.covariance is None else np.asarray(lm.covariance)[3:, 3:]  # (rotation, translation)
        else:
            continue
        if cov is not None:
            e = ellipsoid(stamp, frame, "ellipsoids", lm.id, centre, cov, (1.0, 1.0, 0.2))
            if e is not None:
                out.append(e)
    return out


def truth_markers(stamp: int, frame: str, truth: GroundTruthMap) -> list:
    """The ground truth: objects as their CAD models (class colour, half transparent) with labels,
    pipes as cylinders of their true radius, structures as their CAD meshes."""
    out = [rm.delete_all(stamp, frame)]
    for o in truth.objects:
        rgba = (*class_rgb(o.cls), 0.6)
        T = homogeneous(o.position, o.orientation)
        out.append(_mesh_marker(stamp, frame, "truth_objects", o.id, "object", o.model or o.cls, T, rgba))
        label_at = np.asarray(o.position) + UP * (OBJECT_DIAMETER_M + 2 * LABEL_HEIGHT_M)
        out.append(
            rm.marker(
                stamp,
                frame,
                "truth_labels",
                o.id,
                M.TEXT_VIEW_FACING,
                label_at,
                scale=(0, 0, LABEL_HEIGHT_M),
                rgba=(0.8, 0.8, 0.8, 1),
                text=f"truth {o.id} {o.cls}",
            )
        )
    for p in truth.pipes:
        m = _pipe_marker(stamp, frame, "truth_pipes", p.id, p.p, p.q, p.radius, (0.7, 0.7, 0.7, 0.5))
        if m is not None:
            out.append(m)
    for s in truth.structures:
        out.append(
            _mesh_marker(stamp, frame, "truth_structures", s.id, "structure", s.model, s.matrix(), (0.7, 0.7, 0.7, 0.5))
        )
    return out
