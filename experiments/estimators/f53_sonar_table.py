"""Stop 47 (s47-f53, diagnosis): the sonar observations logged by f53_sonar_log.py against the truth.

    .venv/bin/python experiments/estimators/f53_sonar_table.py A.pkl [B.pkl] [--from S --to S]

For each swath registration (relative pose between two patch anchors): its stamps (s since the first
truth stamp), the relative translation's and yaw's error against the truth's relative pose, and the
front-end's pose_at error at both ends. For each structure view: the structure's world position implied
by the view with the *true* vehicle pose (the view's own error) and with the front-end's pose_at (where
it would place it now), both against the truth's structure position (from the bag's ground-truth map).
"""

from __future__ import annotations

import pickle
import sys

import numpy as np
from scipy.spatial.transform import Rotation


def yaw(R):
    return np.arctan2(R[1, 0], R[0, 0])


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def truth_at(d, stamp_ns):
    st, pos, q = d["truth"]
    st = np.asarray(st, float)
    t = stamp_ns * 1e-9 if st[0] < 1e12 else stamp_ns
    k = int(np.argmin(np.abs(st - t)))
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(q[k]).as_matrix()
    T[:3, 3] = pos[k]
    return T


def rows(d):
    t0 = float(np.asarray(d["truth"][0])[0])
    t0 = t0 * 1e9 if t0 < 1e12 else t0
    out = []
    for e in d["emitted"]:
        s = (e["stamp"] - t0) * 1e-9
        Tn = truth_at(d, e["stamp"])
        if e["type"] == "OdometryObservation":
            Tf = truth_at(d, e["stamp_from"])
            rel_t = np.linalg.inv(Tf) @ Tn
            rel = e["rel"]
            dt = Tf[:3, :3] @ (rel[:3, 3] - rel_t[:3, 3])  # the error in world axes
            dyaw = np.degrees(wrap(yaw(rel[:3, :3]) - yaw(rel_t[:3, :3])))
            out.append(
                (
                    s,
                    f"swath  {(e['stamp_from'] - t0) * 1e-9:7.1f} -> {s:7.1f}  rel err dN,dE,dU "
                    f"{dt[0]:+.3f} {dt[1]:+.3f} {dt[2]:+.3f}  yaw {dyaw:+.2f} deg  sigma_t "
                    f"{np.sqrt(np.diag(e['cov'])[3:]).round(3)}",
                )
            )
        else:
            pt = np.asarray(d["structures"][e["model"]])
            T_view_true = Tn @ e["T_BS"] @ e["T_SM"]
            T_view_nav = e["T_now"] @ e["T_BS"] @ e["T_SM"]
            a, b = T_view_true[:3, 3] - pt, T_view_nav[:3, 3] - pt
            nav = e["T_now"][:3, 3] - Tn[:3, 3]
            dyn = np.degrees(wrap(yaw(e["T_now"][:3, :3]) - yaw(Tn[:3, :3])))
            out.append(
                (
                    s,
                    f"struct {e['model']:8s} {s:7.1f}  view err (true pose) dN,dE {a[0]:+.3f} {a[1]:+.3f}  "
                    f"placed by pose_at dN,dE {b[0]:+.3f} {b[1]:+.3f}  pose_at err dN,dE {nav[0]:+.3f} {nav[1]:+.3f} "
                    f"yaw {dyn:+.2f}  sigma_t {np.sqrt(np.diag(e['cov'])[3:]).round(3)}",
                )
            )
    return out


def main(argv):
    lo, hi = -1e9, 1e9
    if "--from" in argv:
        lo = float(argv[argv.index("--from") + 1])
    if "--to" in argv:
        hi = float(argv[argv.index("--to") + 1])
    files = [a for a in argv if a.endswith(".pkl")]
    for f in files:
        d = pickle.load(open(f, "rb"))
        print(f"== {f}: ATE {d.get('ate')}; swath accepted {len(d['accepted'])}")
        for s, line in rows(d):
            if lo <= s <= hi:
                print("  " + line)
        t0 = float(np.asarray(d["truth"][0])[0])
        t0 = t0 * 1e9 if t0 < 1e12 else t0
        anchors = d["anchors"]
        for v in d.get("views", []):
            s = (v[2] - t0) * 1e-9
            if lo <= s <= hi:
                print(
                    f"  view ICP {v[0]} patch {v[1]} anchor {s:7.1f}: emitted {v[3]} fitness {v[4]:.3f} "
                    f"median {v[5]:.3f} points {v[6]} jump {v[7]:.3f} m turn {v[8]:.2f} deg"
                )
        for r in d["reobservation_log"]:
            s = (anchors.get(r[1], t0) - t0) * 1e-9
            if lo <= s <= hi:
                print(f"  rejected view {r[0]} patch {r[1]} anchor {s:7.1f}: {r[2]} {np.round(r[3:], 3).tolist()}")


if __name__ == "__main__":
    main(sys.argv[1:])
