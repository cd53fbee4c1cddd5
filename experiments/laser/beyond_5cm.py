"""Where the graph's pipeline map is beyond 5 cm of truth (issue 22): every centimetre along the mapped
pipes that ``laser_real_eval.map_scores`` counts beyond 5 cm, split by cause, from the observations
``experiments/laser_real_eval.py pipeline --dump DIR`` recorded (the graph replayed on them, as
``pipeline_replay.py`` does).

    python experiments/laser/beyond_5cm.py --seeds 15,24 --dump DIR [--json OUT]

Causes, in this order (the first that holds):
- ``false``: the mapped pipe lies on no true pipe (its median distance > 10 cm, or > 20° off its nearest
  true pipe's direction): a false line joined the map;
- ``navigation``: within 5 cm once the graph's median position error is taken out of the map (a rigid
  offset of the map with the trajectory: the extents shifted along the line count here too);
- ``past_free_end`` / ``past_fitting_end``: the centimetre lies beyond its nearest true pipe's end (the
  extent grown past it) at a free end / at an end with a fitting (a ground-truth object within 0.3 m:
  a mapped pipe reaching into the fitting's gap between two true pipes counts here);
- ``near_fitting``: within 0.3 m of a ground-truth object (valve, flange, ...);
- ``tilt``: the mapped pipe is more than 2° off its true pipe's direction;
- ``other``.
Also the line observations the front-end reported on no true pipe (placed with the true poses):
their stamp, length, radius and angle to the nearest true pipe, and whether a ground-truth object is
within 0.3 m of them (a fitting's body fitted as a pipe).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent), str(HERE.parent / "estimators")]

from laser_real_eval import PIPE_GATE_M, parse_seeds  # noqa: E402
from pipeline_replay import replay, true_poses  # noqa: E402

FITTING_M = 0.3
CAUSES = ("false", "navigation", "past_free_end", "past_fitting_end", "near_fitting", "tilt", "other")


def _nearest(x: np.ndarray, gt_pipes):
    """Per point: distance to the nearest true axis segment, that pipe's index, its unclipped
    parameter along it and its length."""
    best = np.full(len(x), np.inf)
    which = np.zeros(len(x), int)
    tt = np.zeros(len(x))
    LL = np.zeros(len(x))
    for k, g in enumerate(gt_pipes):
        gp, gq = np.asarray(g.p, float), np.asarray(g.q, float)
        L = np.linalg.norm(gq - gp)
        a = (gq - gp) / L
        t = (x - gp) @ a
        d = np.linalg.norm(x - gp - np.outer(np.clip(t, 0.0, L), a), axis=1)
        better = d < best
        best[better], which[better], tt[better], LL[better] = d[better], k, t[better], L
    return best, which, tt, LL


def split_beyond(landmarks, gt, offset: np.ndarray) -> dict:
    """Length (m) of the mapped pipes beyond 5 cm of truth, by cause (module docstring), and per
    mapped pipe its length, worst error and the length beyond 5 cm by cause."""
    objects = np.array([o.position for o in gt.objects], float).reshape(-1, 3)
    out = dict.fromkeys(CAUSES, 0.0)
    total = 0.0
    rows = []
    for lm in (lm for lm in landmarks if lm.kind == "pipe" and lm.p is not None):
        L = max(float(np.linalg.norm(lm.q - lm.p)), 0.01)
        x = lm.p + np.outer(np.arange(0, 1.0001, 0.01 / L), lm.q - lm.p)
        d, which, t, GL = _nearest(x, gt.pipes)
        total += 0.01 * len(x)
        u = (lm.q - lm.p) / L
        k0 = int(np.bincount(which).argmax())
        g = gt.pipes[k0]
        ga = np.subtract(g.q, g.p) / np.linalg.norm(np.subtract(g.q, g.p))
        angle = float(np.degrees(np.arccos(min(1.0, abs(u @ ga)))))
        false = np.median(d) > 0.10 or angle > 20.0
        d_nav = _nearest(x - offset, gt.pipes)[0]
        beyond = d > PIPE_GATE_M
        cause = np.full(len(x), "", object)
        for i in np.flatnonzero(beyond):
            if false:
                cause[i] = "false"
                continue
            gi = gt.pipes[which[i]]
            if d_nav[i] <= PIPE_GATE_M:
                cause[i] = "navigation"
            elif t[i] < 0.0 or t[i] > GL[i]:
                end = np.asarray(gi.p if t[i] < 0.0 else gi.q, float)
                fit = len(objects) and np.linalg.norm(objects - end, axis=1).min() <= FITTING_M
                cause[i] = "past_fitting_end" if fit else "past_free_end"
            elif len(objects) and np.linalg.norm(objects - x[i], axis=1).min() <= FITTING_M:
                cause[i] = "near_fitting"
            elif angle > 2.0:
                cause[i] = "tilt"
            else:
                cause[i] = "other"
        by = {c: round(0.01 * int((cause == c).sum()), 2) for c in CAUSES if (cause == c).any()}
        for c, v in by.items():
            out[c] += v
        rows.append(
            {
                "id": lm.id,
                "truth": g.id,
                "length_m": round(L, 2),
                "angle_deg": round(angle, 2),
                "error_max_cm": round(100 * float(d.max()), 1),
                "beyond_m": round(0.01 * int(beyond.sum()), 2),
                "beyond_by_cause": by,
            }
        )
    return {
        "mapped_m": round(total, 2),
        "beyond_m": round(sum(out.values()), 2),
        "beyond_by_cause_m": {c: round(v, 2) for c, v in out.items() if v},
        "pipes": rows,
    }


def false_lines(mission, by_stamp) -> list[dict]:
    """The line observations on no true pipe, placed with the true poses (module docstring)."""
    from frontends.laser.evaluation import matching_pipe
    from semslam.observations import LineObservation

    gt = mission.metadata.ground_truth
    objects = np.array([o.position for o in gt.objects], float).reshape(-1, 3)
    pose_at = true_poses(mission)
    t0 = next(iter(mission)).stamp  # the mission's start (the notes' times)
    out = []
    for stamp in sorted(by_stamp):
        T = pose_at(stamp)[1]
        for z in by_stamp[stamp]:
            if not isinstance(z, LineObservation):
                continue
            P = np.stack([z.p, z.q]) @ T[:3, :3].T + T[:3, 3]
            if matching_pipe(P[0], P[1], gt.pipes) is not None:
                continue
            u = (P[1] - P[0]) / np.linalg.norm(P[1] - P[0])
            mid = P.mean(axis=0)
            d, which, _, _ = _nearest(mid[None], gt.pipes)
            g = gt.pipes[int(which[0])]
            ga = np.subtract(g.q, g.p) / np.linalg.norm(np.subtract(g.q, g.p))
            near = float(np.linalg.norm(objects - mid, axis=1).min()) if len(objects) else None
            out.append(
                {
                    "t_s": round((stamp - t0) * 1e-9, 1),
                    "stamp": int(stamp),
                    "length_m": round(float(np.linalg.norm(P[1] - P[0])), 3),
                    "radius_mm": round(1000 * float(z.radius), 1) if z.radius is not None else None,
                    "mid_from_axis_cm": round(100 * float(d[0]), 1),
                    "angle_deg": round(float(np.degrees(np.arccos(min(1.0, abs(u @ ga))))), 1),
                    "fitting_within_m": round(near, 3) if near is not None else None,
                }
            )
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True)
    ap.add_argument("--dump", type=Path, required=True)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    from semslam.mission.measurements import GroundTruthPose

    out = {}
    for seed in parse_seeds(args.seeds):
        results, mission, by_stamp = replay(seed, args.dump, {}, {})
        graph = results["graph"]
        truth = {m.stamp: np.asarray(m.position, float) for m in mission.of_type(GroundTruthPose)}
        stamps = np.array(sorted(truth))
        k = np.searchsorted(stamps, graph.trajectory.stamps).clip(0, len(stamps) - 1)
        offset = np.median(graph.trajectory.positions - np.array([truth[int(s)] for s in stamps[k]]), axis=0)
        r = split_beyond(graph.landmarks, mission.metadata.ground_truth, offset)
        r["false_lines"] = false_lines(mission, by_stamp)
        r["pose_offset_m"] = [round(float(v), 3) for v in offset]
        out[seed] = r
        share = 1.0 - r["beyond_m"] / max(r["mapped_m"], 1e-9)
        print(
            f"seed {seed}: mapped {r['mapped_m']} m, beyond 5 cm {r['beyond_m']} m (within {share:.3f}) "
            f"{r['beyond_by_cause_m']}, pose offset {r['pose_offset_m']} m, false lines {len(r['false_lines'])}",
            flush=True,
        )
        for p in r["pipes"]:
            if p["beyond_m"]:
                print("   pipe", p)
        for f in r["false_lines"]:
            print("   false line", f)
        if args.json is not None:
            args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
