"""Small simulated surveys for the sonar front-end's tests and experiments: a shortened field
mission (:mod:`semslam.sim.field_mission`) centred on chosen structures, and its returns placed
with the true poses."""

from __future__ import annotations

import numpy as np

from semslam.mission.measurements import GroundTruthPose, SonarSwath
from semslam.sim.field import make_field
from semslam.sim.field_config import FieldSimConfig


def survey_config(
    seed: int = 0,
    lines: int = 3,
    line_length_m: float = 34.0,
    centre="manifold",
    east_offset_m: float = 0.0,
    **sections,
) -> FieldSimConfig:
    """A field mission of ``lines`` lines of ``line_length_m`` centred (north/east) on ``centre``: a
    structure model name of the layout, a (north, east) pair, or None (the field's centre);
    ``sections`` override configuration sections (e.g. ``sonar={"n_beams": 256}``)."""
    base: dict = {"seed": seed, "trajectory": {"lines": lines, "line_length_m": line_length_m}}
    for k, v in sections.items():
        base.setdefault(k, {}).update(v)
    cfg = FieldSimConfig.model_validate(base)
    if isinstance(centre, str):
        st = next(s for s in make_field(cfg).structures if s.model == centre)
        centre = (float(st.position[0]), float(st.position[1]) + east_offset_m)
    if centre is not None:
        base["trajectory"]["center_m"] = (float(centre[0]), float(centre[1]))
    return FieldSimConfig.model_validate(base)


def true_points(mission, sensor: str = "sonar") -> np.ndarray:
    """Every sonar return in {W} (north, east, depth), each swath placed with the true pose at its
    stamp (the field writes a ground-truth pose at every swath stamp)."""
    T_BS = mission.metadata.sensors[sensor].T_BS
    poses = {m.stamp: m.matrix() for m in mission if isinstance(m, GroundTruthPose)}
    out = []
    for m in mission:
        if isinstance(m, SonarSwath) and m.sensor == sensor and m.stamp in poses:
            T = poses[m.stamp] @ T_BS
            out.append(m.points() @ T[:3, :3].T + T[:3, 3])
    return np.concatenate(out) if out else np.zeros((0, 3))


def true_structure_pose(mission, model: str) -> np.ndarray:
    """T_WM of the ground-truth structure of ``model``."""
    from scipy.spatial.transform import Rotation

    g = next(s for s in mission.metadata.ground_truth.structures if s.model == model)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(g.orientation).as_matrix()
    T[:3, 3] = g.position
    return T


def yaw_error(T: np.ndarray, T_true: np.ndarray, symmetry: int = 1) -> float:
    """|yaw difference| (rad) modulo the model's symmetry period."""
    period = 2 * np.pi / max(symmetry, 1)
    d = (np.arctan2(T[1, 0], T[0, 0]) - np.arctan2(T_true[1, 0], T_true[0, 0])) % period
    return float(min(d, period - d))
