"""Stop 48 (s48-f60, diagnosis): where two trajectories (TUM files) of one mission part.

    .venv/bin/python experiments/estimators/tum_parting.py A.tum B.tum [T0] [--truth PKL]

B is interpolated at A's stamps; for each the horizontal distance between the two
and their yaw difference. Prints the first stamps where the distance exceeds 1 mm, 1 cm, 5 cm, 10 cm,
the stamps present in one only, and per 20 s window the largest distance. T0 (s, epoch) is the time
origin of the printed stamps (default: the first stamp of A). With --truth (a dump of
f53_sonar_log.py) also each trajectory's horizontal error against the truth per window.
"""

from __future__ import annotations

import pickle
import sys

import numpy as np
from scipy.spatial.transform import Rotation


def read(path):
    a = np.loadtxt(path, comments="#")
    return a[:, 0], a[:, 1:4], Rotation.from_quat(a[:, 4:8]).as_euler("xyz")[:, 2]


def main(argv):
    truth = None
    if "--truth" in argv:
        i = argv.index("--truth")
        truth = pickle.load(open(argv[i + 1], "rb"))["truth"]
        argv = argv[:i] + argv[i + 2 :]
    ta, pa, ya = read(argv[0])
    tb, pb, yb = read(argv[1])
    t0 = float(argv[2]) if len(argv) > 2 else ta[0]
    ka = {round(t * 1000): i for i, t in enumerate(ta)}
    kb = {round(t * 1000): i for i, t in enumerate(tb)}
    only_a = sorted(set(ka) - set(kb))
    only_b = sorted(set(kb) - set(ka))
    # B interpolated at A's stamps (keyframe stamps differ where the two were given different observations)
    ia = np.flatnonzero((ta >= tb[0]) & (ta <= tb[-1]))
    t = ta[ia] - t0
    pbi = np.column_stack([np.interp(ta[ia], tb, pb[:, k]) for k in range(3)])
    ybi = np.interp(ta[ia], tb, np.unwrap(yb))
    dist = np.hypot(*(pa[ia, :2] - pbi[:, :2]).T)
    dyaw = np.degrees((ya[ia] - ybi + np.pi) % (2 * np.pi) - np.pi)
    common = ia
    print(f"matched {len(common)}; only in A {len(only_a)}, only in B {len(only_b)}")
    if only_a or only_b:
        print(" first only-A", [round(k / 1000 - t0, 2) for k in only_a[:6]])
        print(" first only-B", [round(k / 1000 - t0, 2) for k in only_b[:6]])
    for thr in (1e-3, 1e-2, 0.05, 0.10):
        j = np.flatnonzero(dist > thr)
        print(f"first > {thr * 100:g} cm: " + (f"{t[j[0]]:.2f} s ({dist[j[0]]:.4f} m)" if len(j) else "never"))
    if truth is not None:
        st, pos = np.asarray(truth[0], float), np.asarray(truth[1], float)
        st = st if st[0] < 1e12 else st * 1e-9

        def err(tt, pp):
            k = np.clip(np.searchsorted(st, tt), 0, len(st) - 1)
            return pp[:, :2] - pos[k, :2]

        ea, eb = err(ta[ia], pa[ia]), err(ta[ia], pbi)
    for w in range(0, int(t.max()) + 20, 20):
        m = (t >= w) & (t < w + 20)
        if not m.any():
            continue
        line = f"  {w:4d}-{w + 20:4d} s: max |A-B| {dist[m].max():.4f} m, max dyaw {np.abs(dyaw[m]).max():.2f} deg"
        if truth is not None:
            line += (
                f"; mean err vs truth dN,dE A ({ea[m, 0].mean():+.3f}, {ea[m, 1].mean():+.3f})"
                f" B ({eb[m, 0].mean():+.3f}, {eb[m, 1].mean():+.3f})"
            )
        print(line)


if __name__ == "__main__":
    main(sys.argv[1:])
