"""Stop 48 (s48-f60, diagnosis): the re-observations after a long gap, per view, against the truth.

    .venv/bin/python experiments/estimators/gap_view_table.py A.pkl [B.pkl] [--gap M]

Reads dumps of f53_sonar_log.py (with `views_T`). For each re-observation whose gap (track since the
structure's last accepted view) exceeds M (default 25 m = max_jump_m / carry_sigma_per_m of the
default config), keyed by (structure, patch): the ICP from the prior (fitness, median, jump, turn;
whether today's checks pass it) and the structure position it implies with the vehicle's *true*
pose at the patch's anchor, against the truth ("err"); the search's best fit likewise (where the view
was searched); what was done (emitted / refused and why); for an emitted view, its error with the true
pose at the emission stamp (as f53_sonar_table.py), where pose_at placed it, and its σ_t. With two
dumps the rows of both are printed one under the other (A first).
"""

from __future__ import annotations

import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from f53_sonar_table import truth_at  # noqa: E402


def t0_ns(d):
    t0 = float(np.asarray(d["truth"][0])[0])
    return t0 * 1e9 if t0 < 1e12 else t0


def implied_err(d, model, anchor, T_AM):
    """The structure's horizontal position implied by T_AM with the true anchor pose, minus the truth."""
    if T_AM is None:
        return None
    p = (truth_at(d, anchor) @ T_AM)[:3, 3] - np.asarray(d["structures"][model])
    return p[:2]


def emitted_row(d, model, ob):
    for e in d["emitted"]:
        if e["type"] == "StructureObservation" and e["stamp"] == ob["stamp"] and e["model"] == model:
            if np.allclose(e["T_SM"], ob["T_SM"]):
                return e
    return None


def view_rows(d, gap_min):
    t0 = t0_ns(d)
    out = {}
    for v, vT in zip(d["views"], d["views_T"], strict=True):
        model, patch, anchor = v[0], v[1], v[2]
        gap, entry, n_icp = v[9], v[10], v[11]
        if gap <= gap_min:
            continue
        loc_err = implied_err(d, model, anchor, vT[0])
        sea_err = implied_err(d, model, anchor, vT[1])
        if entry is None:
            outcome, local_why = "emitted (ICP from the prior)", None
        elif entry[2] == "searched" and not v[3]:  # the search's view refused by f53_sonar_log's DROP
            outcome, local_why = (
                f"not emitted (DROP; search local fitness {entry[5]:.3f}, moved {entry[10]:.3f} m)",
                entry[4],
            )
        elif entry[2] == "searched":
            outcome, local_why = f"emitted (searched; local fitness {entry[5]:.3f}, moved {entry[10]:.3f} m)", entry[4]
        elif entry[2] == "gap":
            info = entry[3:]
            if info[2] == "no fit":  # (gap, local_why, "no fit", starts)
                outcome, local_why = "refused: gap, no fit", info[1]
                sea_err = None  # the search returns the ICP from the prior when nothing fits
            else:  # (why, gap, local_why, local fitness, fitness, median, ambiguity, sigma, moved)
                why, local_why = info[0], info[2]
                outcome = (
                    f"refused: gap ({why}; search fitness {info[4]:.3f} median {info[5]:.3f} "
                    f"ambiguity {info[6]:.3f} sigma {info[7]:.3f} moved {info[8]:.3f})"
                )
        else:
            outcome, local_why = f"refused: {entry[2]}", entry[2]
        line = (
            f"{model:8s} patch {patch:4d} anchor {(anchor - t0) * 1e-9:6.1f} s gap {gap:6.1f} m ICPs {n_icp:4d} | "
            f"prior ICP fit {v[4]:.3f} med {v[5]:.3f} jump {v[7]:.3f} turn {v[8]:.1f} "
            f"[{'passes' if local_why is None else 'fails ' + str(local_why)}] err "
            + (f"{loc_err[0]:+.3f} {loc_err[1]:+.3f}" if loc_err is not None else "-")
            + " | search err "
            + (f"{sea_err[0]:+.3f} {sea_err[1]:+.3f}" if sea_err is not None else "-")
            + f" | {outcome}"
        )
        if len(vT) > 3 and vT[3] is not None:
            f = vT[3]
            line += (
                f"\n      search fit: points {f['n_structure']}, fitness {f['fitness']:.3f}, footprint coverage "
                f"{f['coverage']:.2f}, unexplained {f['unexplained']:.2f}"
            )
        if vT[2] is not None:
            e = emitted_row(d, model, vT[2])
            if e is not None:
                Tn = truth_at(d, e["stamp"])
                pt = np.asarray(d["structures"][model])
                a = (Tn @ e["T_BS"] @ e["T_SM"])[:3, 3] - pt
                b = (e["T_now"] @ e["T_BS"] @ e["T_SM"])[:3, 3] - pt
                nav = e["T_now"][:3, 3] - Tn[:3, 3]
                line += (
                    f"\n      emitted {(e['stamp'] - t0) * 1e-9:6.1f} s: view err (true pose) {a[0]:+.3f} {a[1]:+.3f}, "
                    f"placed by pose_at {b[0]:+.3f} {b[1]:+.3f}, pose_at err {nav[0]:+.3f} {nav[1]:+.3f}, "
                    f"sigma_t {np.sqrt(np.diag(e['cov'])[3:]).round(3)}"
                )
        out[(model, patch)] = (anchor, line)
    return out


def main(argv):
    gap_min = 25.0
    if "--gap" in argv:
        gap_min = float(argv[argv.index("--gap") + 1])
    files = [a for a in argv if a.endswith(".pkl")]
    dumps = [pickle.load(open(f, "rb")) for f in files]
    for f, d in zip(files, dumps, strict=True):
        print(f"== {f}: ATE {d.get('ate')}")
    rows = [view_rows(d, gap_min) for d in dumps]
    keys = sorted(set().union(*rows), key=lambda k: min(r[k][0] for r in rows if k in r))
    for k in keys:
        for name, r in zip("AB", rows, strict=False):
            print(f"{name} " + (r[k][1] if k in r else f"{k[0]} patch {k[1]}: no view with a gap > {gap_min:g} m"))
        print()


if __name__ == "__main__":
    main(sys.argv[1:])
