"""How far plain dead reckoning of a simulated survey drifts, and how much neighbouring lines disagree.

Dead reckoning here is the simplest honest one: the DVL's velocity moved to the body origin
(lever arm with the AHRS rate), rotated to {W} with the AHRS attitude (slerp at the DVL stamps),
integrated by the trapezoid rule from the first ground-truth pose; during a DVL dropout the last
valid body-frame velocity is held. Depth is left to the pressure sensor, so only the horizontal
error is reported.

The *between-line drift* is what the sonar front-end's swath registration has to correct: where
two neighbouring lines pass the same east coordinate, the difference between their horizontal
navigation errors there, i.e. by how much the two lines' swaths are misplaced against each other.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from semslam.mission.measurements import Attitude, DvlVelocity, GroundTruthPose
from semslam.mission.mission import Mission


def dead_reckoning(mission: Mission) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """At the DVL stamps: (seconds since the mission's first stamp, dead-reckoned body positions
    N×3, true positions N×3)."""
    dvl, att, gt = [], [], []
    for m in mission:
        if isinstance(m, DvlVelocity):
            dvl.append(m)
        elif isinstance(m, Attitude):
            att.append(m)
        elif isinstance(m, GroundTruthPose):
            gt.append(m)
    meta = mission.metadata
    dvl_s = next(s for s in meta.sensors.values() if s.kind == "dvl")
    ahrs_s = next(s for s in meta.sensors.values() if s.kind == "ahrs")
    R_BS_d, t_BS_d = dvl_s.T_BS[:3, :3], dvl_s.T_BS[:3, 3]
    R_BS_a = ahrs_s.T_BS[:3, :3]

    ts = np.array([m.stamp for m in dvl], np.int64)
    ta = np.array([m.stamp for m in att], np.int64)
    tg = np.array([m.stamp for m in gt], np.int64)
    ref = min(ts[0], ta[0], tg[0])
    x = (ts - ref) * 1e-9
    xa = (ta - ref) * 1e-9
    xg = (tg - ref) * 1e-9
    R_WS = Rotation.from_quat([m.orientation for m in att])
    R_WB = Slerp(xa, R_WS * Rotation.from_matrix(R_BS_a).inv())(np.clip(x, xa[0], xa[-1])).as_matrix()
    w_S = np.array([m.angular_rate if m.angular_rate is not None else np.zeros(3) for m in att])
    w_B = np.stack([np.interp(x, xa, w_S[:, k]) for k in range(3)], 1) @ R_BS_a.T

    valid = np.array([m.valid for m in dvl])
    v_S = np.array([m.velocity for m in dvl])
    v_B = v_S @ R_BS_d.T - np.cross(w_B, t_BS_d)
    # hold the last valid body velocity through dropouts (before the first one: zero)
    last = np.maximum.accumulate(np.where(valid, np.arange(len(valid)), -1))
    v_B = np.where((last >= 0)[:, None], v_B[np.maximum(last, 0)], 0.0)
    v_W = np.einsum("nij,nj->ni", R_WB, v_B)

    P_true = np.stack([np.interp(x, xg, [m.position[k] for m in gt]) for k in range(3)], 1)
    steps = 0.5 * (v_W[1:] + v_W[:-1]) * np.diff(x)[:, None]
    P = P_true[0] + np.vstack([np.zeros(3), np.cumsum(steps, 0)])
    return x, P, P_true


def navigation_drift(mission: Mission, lines: list[dict] | None = None, step_m: float = 0.5) -> dict:
    """Horizontal dead-reckoning error (final, max) and the between-line drift over the survey
    ``lines`` (default ``extras["trajectory"]["lines"]``): median, 95th percentile and max over the
    east positions (every ``step_m``) that neighbouring lines share, and the max per pair."""
    x, P, P_true = dead_reckoning(mission)
    err = (P - P_true)[:, :2]
    lines = lines if lines is not None else mission.metadata.extras.get("trajectory", {}).get("lines", [])
    out = {
        "method": "DVL + AHRS dead reckoning from the first ground-truth pose (semslam.sim.drift)",
        "final_m": float(np.linalg.norm(err[-1])),
        "max_m": float(np.linalg.norm(err, axis=1).max()),
    }
    pair_max, all_d = [], []
    for a, b in zip(lines, lines[1:]):
        lo = max(min(a["east_from_m"], a["east_to_m"]), min(b["east_from_m"], b["east_to_m"]))
        hi = min(max(a["east_from_m"], a["east_to_m"]), max(b["east_from_m"], b["east_to_m"]))
        if hi <= lo:
            continue
        e = np.arange(lo, hi + 1e-9, step_m)

        def when(line):  # mission time (s) at which the line passes east e
            f = (e - line["east_from_m"]) / (line["east_to_m"] - line["east_from_m"])  # noqa: B023
            return line["t_start_s"] + f * (line["t_end_s"] - line["t_start_s"])

        ta, tb = when(a), when(b)
        ok = (ta >= x[0]) & (ta <= x[-1]) & (tb >= x[0]) & (tb <= x[-1])
        if not ok.any():
            continue
        ea = np.stack([np.interp(ta[ok], x, err[:, k]) for k in range(2)], 1)
        eb = np.stack([np.interp(tb[ok], x, err[:, k]) for k in range(2)], 1)
        d = np.linalg.norm(ea - eb, axis=1)
        pair_max.append(float(d.max()))
        all_d.append(d)
    if all_d:
        d = np.concatenate(all_d)
        out.update(
            between_lines_median_m=float(np.median(d)),
            between_lines_p95_m=float(np.quantile(d, 0.95)),
            between_lines_max_m=float(d.max()),
            between_lines_max_per_pair_m=pair_max,
        )
    return out
