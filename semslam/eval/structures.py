"""Registered structures (the sonar front-end's CAD registrations) against the ground truth.

A structure counts as found only when a registration of its model lies at the right place: its
position within :data:`POSITION_TOL_M` of the truth and its yaw (modulo the model's symmetry)
within :data:`YAW_TOL_DEG`. A registration that is not at the right place of any structure is a
false structure, and the true structure it was meant for is missed; when a truth of its model lies
within :data:`WRONG_PLACE_GATE_M` it is flagged ``wrong_place`` (registered on a structure, but
wrongly), else it is a false structure on the seabed.

Why these tolerances: the registered pose is read in the final map, so its error is the
registration's (centimetres and ~1° when right, see frontends/sonar/README.md) plus the navigation
error where the structure was seen: on the simulated fields the graph's ATE reaches 0.7 m and a
well-fitting registration (fitness 0.96) sat 1.1 m from the truth. The yaw error, by contrast, stays
within 2° when the registration is right (the AHRS heading bias drifts 1.5° over a mission), while
a near-symmetric structure turned end for end is 180° off. So 5° in yaw is the sharp test, and
1 m in position tells a registration on the structure from one on something else (a structure
slid by a manifold bay, or a model fitted to a pipe junction), not a slide shorter than the
navigation error: the front-end's own quality test (fitness on all the data) is the one for those.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.mission.ground_truth import GroundTruthMap

POSITION_TOL_M = 1.0
YAW_TOL_DEG = 5.0
WRONG_PLACE_GATE_M = 3.0


def _yaw(R: np.ndarray) -> float:
    """Heading of a rotation about the world's vertical (NED: z down)."""
    return float(np.arctan2(R[1, 0], R[0, 0]))


def _errors(pose, symmetry: int, position, orientation) -> tuple[float, float]:
    """(position error m, yaw error ° modulo the symmetry) of a registered pose against a truth."""
    T = np.asarray(pose, float)
    d = float(np.linalg.norm(T[:3, 3] - np.asarray(position, float)))
    period = 2 * np.pi / max(int(symmetry), 1)
    dyaw = (_yaw(T[:3, :3]) - _yaw(Rotation.from_quat(orientation).as_matrix())) % period
    return d, float(np.degrees(min(dyaw, period - dyaw)))


def structure_rows(registered: list[dict], truth: GroundTruthMap) -> list[dict]:
    """One row per seen true structure (``found``, its errors when found, ``registered_wrong_place``
    when a registration of its model lies near it at the wrong pose), then one per registration at
    no right place (``truth_id`` None, ``found`` False, ``wrong_place``, errors against the nearest
    truth of its model). ``registered``: the front-end's rows (``model``, ``pose`` T_W,model,
    ``median_error_m``, ``symmetry``)."""
    seen = set(truth.seen_structures) if truth.seen_structures is not None else {g.id for g in truth.structures}
    used: set[int] = set()
    rows = []
    near_wrong: dict[int, int] = {}
    for g in truth.structures:
        if g.id not in seen:
            continue
        best, best_d = None, np.inf
        for k, s in enumerate(registered):
            if k in used or s["model"] != g.model:
                continue
            d, dyaw = _errors(s["pose"], s.get("symmetry", 1), g.position, g.orientation)
            if d <= POSITION_TOL_M and dyaw <= YAW_TOL_DEG and d < best_d:
                best, best_d = k, d
        row = {
            "model": g.model,
            "truth_id": g.id,
            "found": best is not None,
            "median_error_m": None,
            "yaw_error_deg": None,
            "position_error_m": None,
        }
        if best is not None:
            used.add(best)
            s = registered[best]
            d, dyaw = _errors(s["pose"], s.get("symmetry", 1), g.position, g.orientation)
            row.update(median_error_m=s.get("median_error_m"), yaw_error_deg=dyaw, position_error_m=d)
        rows.append(row)
    for k, s in enumerate(registered):
        if k in used:
            continue
        errs = [
            (*_errors(s["pose"], s.get("symmetry", 1), g.position, g.orientation), g.id)
            for g in truth.structures
            if g.model == s["model"]
        ]
        d, dyaw, gid = min(errs) if errs else (None, None, None)
        wrong = d is not None and d <= WRONG_PLACE_GATE_M
        if wrong:
            near_wrong[gid] = k
        rows.append(
            {
                "model": s["model"],
                "truth_id": None,
                "found": False,
                "wrong_place": wrong,
                "wrong_place_of": gid if wrong else None,
                "median_error_m": s.get("median_error_m"),
                "yaw_error_deg": dyaw,
                "position_error_m": d,
            }
        )
    for row in rows:
        if row["truth_id"] is not None and not row["found"]:
            row["registered_wrong_place"] = row["truth_id"] in near_wrong
    return rows


def structure_counts(rows: list[dict]) -> dict:
    """found / missed / false (of which wrong place) over :func:`structure_rows`, and the tolerances."""
    true = [r for r in rows if r["truth_id"] is not None]
    false = [r for r in rows if r["truth_id"] is None]
    return {
        "structures_seen": len(true),
        "structures_found": sum(r["found"] for r in true),
        "structures_missed": sum(not r["found"] for r in true),
        "structures_false": len(false),
        "structures_wrong_place": sum(bool(r.get("wrong_place")) for r in false),
        "structure_tolerance": {"position_m": POSITION_TOL_M, "yaw_deg": YAW_TOL_DEG},
    }
